"""Inference (paper 3.2.6): score refined candidates against the real frame and keep the better one."""

from __future__ import annotations

from typing import NamedTuple, Sequence

import torch

from trioman.toolkit.examiner.model import Examiner


class BatchChoice(NamedTuple):
    """Per sample: index of the higher-scoring candidate [B] (long), its score [B], keep flag [B] (bool)."""

    index: torch.Tensor
    score: torch.Tensor
    keep: torch.Tensor


@torch.no_grad()
def choose(
    model: Examiner,
    candidates: torch.Tensor | Sequence[torch.Tensor],
    real: torch.Tensor,
    threshold: float | None = None,
) -> BatchChoice:
    """Pick, per sample, the candidate most similar to ``real``.

    candidates: [K, B, 3, S, S] or a sequence of K tensors [B, 3, S, S]; real: [B, 3, S, S].
    keep is ``score >= threshold``, or all True when threshold is None. Ties go to the lower index.
    All K*B pairs are scored in one batch.
    """
    if not isinstance(candidates, torch.Tensor):
        candidates = torch.stack(list(candidates))
    model.check_images("real", real)
    if candidates.ndim != 5 or candidates.shape[0] < 1 or candidates.shape[1:] != real.shape:
        raise ValueError(f"candidates: expected shape [K, {', '.join(map(str, real.shape))}], got {list(candidates.shape)}")
    if threshold is not None and not 0.0 <= threshold <= 1.0:
        raise ValueError(f"threshold: must lie in [0, 1], got {threshold}")
    k, b = candidates.shape[:2]
    scores = model(candidates.reshape(k * b, *real.shape[1:]), real.repeat(k, 1, 1, 1)).reshape(k, b)
    score, index = scores.max(dim=0)
    keep = torch.ones_like(score, dtype=torch.bool) if threshold is None else score >= threshold
    return BatchChoice(index, score, keep)
