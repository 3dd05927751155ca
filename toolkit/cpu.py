"""CPU speed settings that change process-wide state, scoped so callers get their state back."""

from __future__ import annotations

import contextlib
from typing import Iterator

import torch


def denormals_flushed() -> bool:
    """Whether float operations currently flush subnormal results to zero."""
    return float(torch.tensor([2e-38], dtype=torch.float32) * 0.01) == 0.0


@contextlib.contextmanager
def flush_denormals() -> Iterator[None]:
    """Flush subnormal floats to zero inside the block (they cost up to 10x in the MLPs and the
    rasterizer on CPU) and restore the previous setting after it; usable as a decorator."""
    previous = denormals_flushed()
    torch.set_flush_denormal(True)
    try:
        yield
    finally:
        torch.set_flush_denormal(previous)
