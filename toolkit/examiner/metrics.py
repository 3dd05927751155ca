"""AUROC of Examiner scores (rank-based, no sklearn), and of a model on real vs coarse pairs."""

from __future__ import annotations

import numpy as np
import torch


def auroc(scores: torch.Tensor | np.ndarray, labels: torch.Tensor | np.ndarray) -> float:
    """Area under the ROC curve of ``scores`` [M] for binary ``labels`` [M] (1 = positive).

    Mann-Whitney U with average ranks, so tied scores count one half: equals P(s+ > s-) + P(s+ = s-)/2.
    """
    s = np.asarray(scores.detach().cpu() if isinstance(scores, torch.Tensor) else scores, dtype=np.float64).ravel()
    y = np.asarray(labels.detach().cpu() if isinstance(labels, torch.Tensor) else labels).ravel()
    if s.shape != y.shape:
        raise ValueError(f"labels: {y.size} labels for {s.size} scores")
    if not np.isfinite(s).all():
        raise ValueError("scores: contain NaN/Inf")
    if not np.isin(y, (0, 1)).all():
        raise ValueError("labels: must be 0 or 1")
    pos = y == 1
    n_pos, n_neg = int(pos.sum()), int((~pos).sum())
    if n_pos == 0 or n_neg == 0:
        raise ValueError(f"labels: AUROC needs both classes, got {n_pos} positives and {n_neg} negatives")
    order = np.argsort(s, kind="mergesort")
    sorted_s = s[order]
    ranks = np.empty(s.size)
    # average rank (1-based) of each run of equal scores
    starts = np.flatnonzero(np.r_[True, sorted_s[1:] != sorted_s[:-1]])
    ends = np.r_[starts[1:], s.size]
    ranks[order] = np.repeat((starts + ends + 1) / 2.0, ends - starts)
    return float((ranks[pos].sum() - n_pos * (n_pos + 1) / 2.0) / (n_pos * n_neg))


@torch.no_grad()
def pair_auroc(model: torch.nn.Module, gt: torch.Tensor, coarse: torch.Tensor, reference: torch.Tensor,
               batch: int = 16) -> float:
    """AUROC of ``model(candidate, reference)`` separating real pairs (gt, reference) from coarse
    pairs (coarse, reference); each [B, 3, S, S], scored ``batch`` pairs at a time."""
    def score(cand: torch.Tensor) -> torch.Tensor:
        return torch.cat([model(cand[i:i + batch], reference[i:i + batch]) for i in range(0, len(cand), batch)])

    n = len(gt)
    return auroc(torch.cat([score(gt), score(coarse)]), torch.cat([torch.ones(n), torch.zeros(n)]))
