"""Training pairs of the paper's Examiner (3.2.6), from samples (I^T, I_c^T, I^{T+k})."""

from __future__ import annotations

from typing import NamedTuple

import torch


class ExaminerBatch(NamedTuple):
    """One batch of data-construction samples (paper 3.2.4), each float [B, 3, H, W] in [0, 1]."""

    gt: torch.Tensor  # I^T, the real frame at time T
    coarse: torch.Tensor  # I_c^T, the avatar's render of frame T
    reference: torch.Tensor  # I^{T+k}, a real frame of the same subject at another time


PAIRINGS = ("contrast", "paper")


class ExaminerPairs(NamedTuple):
    """(candidate, reference) pairs [2B, 3, H, W] and their target similarity [2B] in {0, 1}."""

    candidate: torch.Tensor
    reference: torch.Tensor
    target: torch.Tensor


def check_batch(batch: ExaminerBatch) -> None:
    """ValueError naming the field unless the three fields are float tensors of one shape [B, 3, H, W]."""
    shape = None
    for name, x in zip(ExaminerBatch._fields, batch):
        if not isinstance(x, torch.Tensor) or not x.is_floating_point():
            raise ValueError(f"{name}: expected a float tensor, got {getattr(x, 'dtype', type(x).__name__)}")
        if x.ndim != 4 or x.shape[1] != 3 or x.shape[0] == 0:
            raise ValueError(f"{name}: expected shape [B, 3, H, W] with B >= 1, got {list(x.shape)}")
        if shape is not None and x.shape != shape:
            raise ValueError(f"{name}: shape {list(x.shape)} differs from gt's {list(shape)}")
        shape = x.shape


def sample_pairs(batch: ExaminerBatch, rng: torch.Generator, pairing: str = "contrast",
                 shard: tuple[int, int] = (0, 1)) -> ExaminerPairs:
    """Training pairs from B samples. The paper's three kinds of pair:

    - (I^{T+k}, I^{T+k}) -> 1: "the branch with I^{T+k} as the sole input";
    - (I^T, I^{T+k}) -> 1, a real frame;  (I_c^T, I^{T+k}) -> 0, a coarse frame.

    ``pairing="paper"``: 2B pairs, the identical one of every sample (first B rows) and, with equal
    probability (coin flips from ``rng``), its real or its coarse pair (last B rows); over many draws
    1/2 identical, 1/4 real, 1/4 coarse.
    ``pairing="contrast"`` (default): 2B pairs, every sample's real pair (first B rows) and coarse
    pair (last B rows): the two frames meet the same reference in the same step. Identical pairs are
    left out because they teach "candidate equals reference", which no real frame at another time is
    (docs/findings.md, "Examiner").

    ``shard`` (rank, world size): ``batch`` is that rank's B rows of a global batch of world size x B;
    the coin flips are drawn for the global batch and the rank's rows taken, so every rank's
    generator stays in step and the ranks together draw what one process would.
    """
    check_batch(batch)
    if pairing not in PAIRINGS:
        raise ValueError(f"pairing: expected one of {PAIRINGS}, got {pairing!r}")
    b, dev, dt = batch.gt.shape[0], batch.gt.device, batch.gt.dtype
    ref = batch.reference
    if pairing == "contrast":
        target = torch.cat([torch.ones(b), torch.zeros(b)]).to(dev, dt)
        return ExaminerPairs(torch.cat([batch.gt, batch.coarse]), torch.cat([ref, ref]), target)
    rank, world = shard
    use_real = (torch.rand(b * world, generator=rng) < 0.5)[rank * b:(rank + 1) * b]  # [B]
    chosen = torch.where(use_real.to(dev)[:, None, None, None], batch.gt, batch.coarse)
    target = torch.cat([torch.ones(b), use_real.float()]).to(dev, dt)
    return ExaminerPairs(torch.cat([ref, chosen]), torch.cat([ref, ref]), target)
