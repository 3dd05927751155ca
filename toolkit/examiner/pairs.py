"""Training pairs of the paper's Examiner (3.2.6), from samples (I^T, I_c^T, I^{T+k})."""

from __future__ import annotations

from typing import NamedTuple

import torch


class ExaminerBatch(NamedTuple):
    """One batch of data-construction samples (paper 3.2.4), each float [B, 3, H, W] in [0, 1]."""

    gt: torch.Tensor  # I^T, the real frame at time T
    coarse: torch.Tensor  # I_c^T, the avatar's render of frame T
    reference: torch.Tensor  # I^{T+k}, a real frame of the same subject at another time


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


def sample_pairs(batch: ExaminerBatch, rng: torch.Generator) -> ExaminerPairs:
    """Two pairs per sample, as in the paper:

    - (I^{T+k}, I^{T+k}) -> 1: "the branch with I^{T+k} as the sole input";
    - with equal probability (I_c^T, I^{T+k}) -> 0 or (I^T, I^{T+k}) -> 1.

    So over many draws 1/2 of the pairs are identical, 1/4 coarse (target 0) and 1/4 real
    (target 1); 3/4 of the targets are 1. The first B rows are the identical pairs, the last B the
    interaction pairs in sample order. ``rng`` (a seeded torch.Generator) draws the coin flips.
    """
    check_batch(batch)
    b = batch.gt.shape[0]
    use_real = torch.rand(b, generator=rng) < 0.5  # [B]
    chosen = torch.where(use_real.to(batch.gt.device)[:, None, None, None], batch.gt, batch.coarse)
    target = torch.cat([torch.ones(b), use_real.float()]).to(batch.gt.device, batch.gt.dtype)
    return ExaminerPairs(torch.cat([batch.reference, chosen]), torch.cat([batch.reference, batch.reference]), target)
