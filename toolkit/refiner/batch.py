"""Refiner training batches (paper 3.2.4 triplets) and their mapping to model inputs and targets."""

from __future__ import annotations

from typing import NamedTuple

import torch

from trioman.toolkit.refiner.config import ALIGNED_CONDITIONS, CONDITIONS, VIEW_COUNT


class RefinerBatch(NamedTuple):
    """Float tensors [B, 3, H, W] in [0, 1]."""

    coarse: torch.Tensor  # I_c^T, the Generator's render
    reference: torch.Tensor  # I^{T+k}, the source GT frame (input of the texture view)
    normal: torch.Tensor  # I_g^T, the body normal map (input and target of the geometry view)
    target: torch.Tensor  # I^T, the target of the coarse view
    reference_target: torch.Tensor  # target of the texture view (I^{T+k} itself in the paper)
    aligned: torch.Tensor | None = None  # conditions "warp*": real pixels carried to T from other frames, coarse elsewhere


def _views(conditions: str) -> int:
    if conditions not in CONDITIONS:
        raise ValueError(f"conditions: expected one of {CONDITIONS}, got {conditions!r}")
    return VIEW_COUNT[conditions]


def check_batch(batch: RefinerBatch) -> None:
    """Raise ValueError naming the field for a non-tensor, misshapen, mismatched or non-finite field."""
    shape = None
    for name, x in zip(RefinerBatch._fields, batch):
        if name == "aligned" and x is None:
            continue
        if not isinstance(x, torch.Tensor) or not x.is_floating_point():
            raise ValueError(f"{name}: expected a float torch.Tensor [B, 3, H, W], got {type(x).__name__}")
        if x.ndim != 4 or x.shape[1] != 3:
            raise ValueError(f"{name}: expected shape [B, 3, H, W], got {tuple(x.shape)}")
        if shape is not None and x.shape != shape:
            raise ValueError(f"{name}: shape {tuple(x.shape)} differs from coarse {tuple(shape)}")
        shape = x.shape
        if not torch.isfinite(x).all():
            raise ValueError(f"{name}: contains NaN/Inf")


def refiner_inputs(batch: RefinerBatch, conditions: str) -> tuple[torch.Tensor, ...]:
    """The model inputs (coarse[, reference[, normal]]) for ``conditions``; with "warp*" the reference
    input is ``batch.aligned``."""
    views = _views(conditions)
    if conditions in ALIGNED_CONDITIONS:
        if batch.aligned is None:
            raise ValueError(f"aligned: required with conditions={conditions!r} (triplets without aligned references: "
                             "build them again)")
        return (batch.coarse, batch.aligned, batch.normal)[:views]
    return (batch.coarse, batch.reference, batch.normal)[:views]


def refiner_targets(batch: RefinerBatch, conditions: str) -> torch.Tensor:
    """Targets [B, V, 3, H, W] in view order: I^T (coarse view), I^{T+k} (texture), I_g^T (geometry); with
    "warp*" (aligned view, coarse view[, geometry]): I^T for both image views."""
    views = _views(conditions)
    second = batch.target if conditions in ALIGNED_CONDITIONS else batch.reference_target
    return torch.stack((batch.target, second, batch.normal)[:views], dim=1)
