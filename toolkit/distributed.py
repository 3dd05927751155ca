"""Data-parallel training across processes (``torchrun``): the process group, this rank's rows of a
global batch, DDP wrapping and the agreement of ranks on per-step decisions (docs/scaling.md); the
training devices and mixed-precision choices.

Rules: one process (no ``torchrun``, or ``WORLD_SIZE`` 1) creates no group and wraps nothing, so it
runs exactly the single-process code; with N processes every rank draws the same global batch of
N x B samples from the run's one seeded stream and trains on its own B rows, DDP averages the
gradients, and rank 0 alone writes files.
"""

from __future__ import annotations

import gc
import os
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Iterator

import torch
import torch.distributed as dist
from torch import nn

DEVICES = ("cpu", "cuda")
MIXED_PRECISION = ("no", "bf16")  # the training loops' autocast choices; bf16 needs no loss scaling


@dataclass(frozen=True)
class Ranks:
    """Where this process stands in the group; the defaults are a single process."""

    rank: int = 0
    world_size: int = 1
    local_rank: int = 0  # the rank on this machine: its GPU index
    backend: str | None = None  # "gloo" (CPU) or "nccl" (CUDA); None without a group

    @property
    def main(self) -> bool:
        """Rank 0: the one that writes checkpoints, fit.json and progress."""
        return self.rank == 0

    def rows(self, batch: int) -> slice:
        """This rank's rows of a global batch of ``world_size`` x ``batch`` samples."""
        return slice(self.rank * batch, (self.rank + 1) * batch)

    def record(self, batch: int, seed: int) -> dict:
        """What fit.json records of the run's ranks: every rank's seed (the run's: one shared sample
        stream) and its rows of each global batch."""
        return {"world_size": self.world_size, "backend": self.backend, "batch_per_rank": batch,
                "global_batch": batch * self.world_size,
                "ranks": [{"rank": r, "seed": seed, "rows": [r * batch, (r + 1) * batch]} for r in range(self.world_size)]}


def _env_int(name: str, default: int) -> int:
    value = os.environ.get(name)
    if value is None:
        return default
    try:
        return int(value)
    except ValueError:
        raise ValueError(f"{name}: expected an integer (set by torchrun), got {value!r}") from None


def from_env() -> Ranks:
    """The ranks torchrun announces in WORLD_SIZE, RANK and LOCAL_RANK (a single process without them)."""
    world = _env_int("WORLD_SIZE", 1)
    rank, local = _env_int("RANK", 0), _env_int("LOCAL_RANK", 0)
    if world < 1 or not 0 <= rank < world:
        raise ValueError(f"RANK/WORLD_SIZE: rank {rank} outside a world of {world} processes")
    return Ranks(rank, world, local)


def check_device(device: str) -> None:
    """ValueError naming ``device`` unless it is cpu or cuda, and cuda is present when asked for."""
    if device not in DEVICES:
        raise ValueError(f"device: expected one of {DEVICES}, got {device!r}")
    if device == "cuda" and not torch.cuda.is_available():
        raise ValueError("device cuda: CUDA is not available (torch.cuda.is_available() is False)")


@contextmanager
def process_group(device: str = "cpu") -> Iterator[Ranks]:
    """The process group of a torchrun launch for the whole ``with`` body (gloo on CPU, nccl on
    CUDA, each rank on the GPU of its local rank), destroyed at the end; a single process gets
    ``Ranks()`` and no group."""
    check_device(device)
    ranks = from_env()
    if ranks.world_size == 1:
        yield ranks
        return
    backend = "nccl" if device == "cuda" else "gloo"
    if device == "cuda":
        torch.cuda.set_device(ranks.local_rank)
    dist.init_process_group(backend)
    try:
        yield Ranks(ranks.rank, ranks.world_size, ranks.local_rank, backend)
    finally:
        gc.collect()  # frees models (DDP) in reference cycles that would keep the group's threads alive to exit
        dist.destroy_process_group()


def current() -> Ranks:
    """This process's ranks in the initialised group, ``Ranks()`` when there is none."""
    if not (dist.is_available() and dist.is_initialized()):
        return Ranks()
    return Ranks(dist.get_rank(), dist.get_world_size(), from_env().local_rank, dist.get_backend())


def torch_device(device: str, ranks: Ranks) -> torch.device:
    """``device`` for this rank: cuda means the GPU of its local rank."""
    check_device(device)
    return torch.device("cuda", ranks.local_rank) if device == "cuda" and ranks.world_size > 1 else torch.device(device)


def barrier() -> None:
    """Wait for every rank (nothing without a group): a function whose files rank 0 writes ends
    with it, so no rank reads the run folder before they are there."""
    if current().world_size > 1:
        dist.barrier()


def all_ranks(flag: bool) -> bool:
    """True when ``flag`` is True on every rank (a MIN all-reduce); ``flag`` itself without a group.
    Every rank must call it at the same point of the step."""
    ranks = current()
    if ranks.world_size == 1:
        return flag
    device = torch.device("cuda", torch.cuda.current_device()) if ranks.backend == "nccl" else torch.device("cpu")
    t = torch.tensor([int(flag)], dtype=torch.int32, device=device)
    dist.all_reduce(t, op=dist.ReduceOp.MIN)
    return bool(t.item())


def data_parallel(model: nn.Module) -> nn.Module:
    """``model`` under DistributedDataParallel when a group of more than one rank is initialised (its
    gradients averaged over the ranks in backward), else ``model`` itself. Buffers are not
    broadcast each step: the models hold no running statistics."""
    ranks = current()
    if ranks.world_size == 1:
        return model
    ids = [ranks.local_rank] if ranks.backend == "nccl" else None
    return nn.parallel.DistributedDataParallel(model, device_ids=ids, forward_sync_buffers=False)


def check_world_size(saved: int, ranks: Ranks, where: object) -> None:
    """A checkpoint written at ``saved`` ranks resumes only at the same world size: the sample stream
    is the same, but a sum of gradients over a different split of the batch rounds differently."""
    if saved != ranks.world_size:
        raise ValueError(f"world_size: {where} was written by a run of {saved} process(es), this one has "
                         f"{ranks.world_size}; resume it with {saved} in all (torchrun --nnodes x --nproc-per-node), "
                         f"or start a new run folder")
