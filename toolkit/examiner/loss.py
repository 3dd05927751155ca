"""The Examiner's loss: binary cross-entropy on the similarity score."""

from __future__ import annotations

import torch
import torch.nn.functional as F

from trioman.toolkit.examiner.model import PatchLogits


def examiner_loss(logits: PatchLogits, target: torch.Tensor) -> torch.Tensor:
    """Mean BCE(score, target) with score = sum_n softmax(w)_n sigmoid(s)_n; logits [B, N], target [B].

    Computed in log space (log score = logsumexp(log_softmax(w) + logsigmoid(s)), and the same with
    -s for 1 - score), so it equals ``F.binary_cross_entropy(score, target)`` without its clamp and
    stays finite for saturated scores.
    """
    if target.ndim != 1 or target.shape[0] != logits.scores.shape[0]:
        raise ValueError(f"target: expected shape [{logits.scores.shape[0]}], got {list(target.shape)}")
    log_w = logits.weights.log_softmax(dim=-1)
    log_p = torch.logsumexp(log_w + F.logsigmoid(logits.scores), dim=-1)  # log score
    log_q = torch.logsumexp(log_w + F.logsigmoid(-logits.scores), dim=-1)  # log (1 - score)
    return -(target * log_p + (1 - target) * log_q).mean()
