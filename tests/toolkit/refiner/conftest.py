"""Refiner tests run torch on one thread: on a shared machine two OpenMP threads competing with
another process for the cores make these tiny models tens of times slower."""

from __future__ import annotations

import pytest
import torch


@pytest.fixture(autouse=True)
def one_thread():
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)
