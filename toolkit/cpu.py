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


@contextlib.contextmanager
def deterministic_kernels(enabled: bool = True) -> Iterator[None]:
    """torch's deterministic kernels inside the block, the previous setting after it; usable as a decorator.

    With them the same seed gives the same weights at a given thread count: the CPU backward of an index
    with repeated entries (the avatar's Laplacian) otherwise accumulates in a thread-dependent order.
    Uninitialised memory is not filled (torch's default in this mode): filling costs time, decides nothing.
    """
    previous = (torch.are_deterministic_algorithms_enabled(), torch.is_deterministic_algorithms_warn_only_enabled(),
                torch.utils.deterministic.fill_uninitialized_memory)
    torch.use_deterministic_algorithms(enabled)
    torch.utils.deterministic.fill_uninitialized_memory = False
    try:
        yield
    finally:
        torch.use_deterministic_algorithms(previous[0], warn_only=previous[1])
        torch.utils.deterministic.fill_uninitialized_memory = previous[2]
