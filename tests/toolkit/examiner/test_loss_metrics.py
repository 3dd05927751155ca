"""BCE on the score and the rank-based AUROC."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from trioman.toolkit.examiner import PatchLogits, auroc, examiner_loss


def test_loss_is_bce_on_the_score():
    g = torch.Generator().manual_seed(0)
    logits = PatchLogits(torch.randn(6, 10, generator=g), torch.randn(6, 10, generator=g))
    target = torch.tensor([1.0, 0.0, 1.0, 1.0, 0.0, 1.0])
    expected = F.binary_cross_entropy(logits.score(), target)
    torch.testing.assert_close(examiner_loss(logits, target), expected)


def test_loss_is_finite_for_saturated_scores():
    scores = torch.full((2, 4), 80.0, requires_grad=True)
    logits = PatchLogits(scores, torch.zeros(2, 4))
    loss = examiner_loss(logits, torch.tensor([0.0, 1.0]))
    loss.backward()
    assert torch.isfinite(loss) and loss > 30  # confidently wrong for the first sample
    assert torch.isfinite(scores.grad).all()
    with pytest.raises(ValueError, match=r"target: expected shape \[2\]"):
        examiner_loss(logits, torch.zeros(3))


def _brute_auroc(s, y):
    pos, neg = s[y == 1], s[y == 0]
    pairs = list(itertools.product(pos, neg))
    return sum(1.0 if p > n else 0.5 if p == n else 0.0 for p, n in pairs) / len(pairs)


def test_auroc_matches_pair_counting_with_ties():
    rng = np.random.default_rng(0)
    for _ in range(20):
        s = rng.integers(0, 5, size=30).astype(float)  # many ties
        y = rng.integers(0, 2, size=30)
        y[:2] = (0, 1)
        assert auroc(s, y) == pytest.approx(_brute_auroc(s, y))
    assert auroc(torch.tensor([0.1, 0.9, 0.5]), torch.tensor([0, 1, 1])) == 1.0
    assert auroc([0.3, 0.3], [0, 1]) == 0.5


def test_auroc_input_errors():
    with pytest.raises(ValueError, match="labels: AUROC needs both classes"):
        auroc([0.1, 0.2], [1, 1])
    with pytest.raises(ValueError, match="labels: 2 labels for 3 scores"):
        auroc([0.1, 0.2, 0.3], [0, 1])
    with pytest.raises(ValueError, match="scores: contain NaN"):
        auroc([0.1, float("nan")], [0, 1])
