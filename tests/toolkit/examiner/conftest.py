"""The Examiner tests run tiny models: one intra-op thread is faster than several (and far faster
on a shared, loaded machine); the previous thread count is restored afterwards."""

from __future__ import annotations

import pytest
import torch


@pytest.fixture(autouse=True, scope="package")
def _one_thread():
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(previous)
