"""Training pairs: the paper's proportions, the contrast default, seeding, and input checks."""

from __future__ import annotations

import pytest
import torch

from trioman.toolkit.examiner import ExaminerBatch, sample_pairs


def _batch(b: int) -> ExaminerBatch:
    """gt = 1, coarse = 0, reference = 0.5 everywhere: each pair's members are recognisable."""
    shape = (b, 3, 4, 4)
    return ExaminerBatch(gt=torch.ones(shape), coarse=torch.zeros(shape), reference=torch.full(shape, 0.5))


def test_pairs_follow_the_paper():
    rng = torch.Generator().manual_seed(0)
    counts = {"identical": 0, "coarse": 0, "real": 0}
    for _ in range(200):
        pairs = sample_pairs(_batch(16), rng, "paper")
        assert pairs.candidate.shape == pairs.reference.shape == (32, 3, 4, 4) and pairs.target.shape == (32,)
        assert (pairs.reference == 0.5).all()
        cand = pairs.candidate[:, 0, 0, 0]
        identical, coarse, real = cand == 0.5, cand == 0.0, cand == 1.0
        assert (identical | coarse | real).all()
        assert identical[:16].all()  # one identical pair per sample, first
        assert (pairs.target[identical] == 1).all() and (pairs.target[real] == 1).all() and (pairs.target[coarse] == 0).all()
        counts["identical"] += int(identical.sum())
        counts["coarse"] += int(coarse.sum())
        counts["real"] += int(real.sum())
    total = sum(counts.values())
    assert counts["identical"] / total == 0.5
    assert abs(counts["coarse"] / total - 0.25) < 0.01  # 6400 pairs: std of the fraction ~0.004
    assert abs(counts["real"] / total - 0.25) < 0.01


def test_contrast_default_pairs_every_real_and_coarse_frame():
    pairs = sample_pairs(_batch(5), torch.Generator().manual_seed(0))
    assert pairs.candidate.shape == pairs.reference.shape == (10, 3, 4, 4)
    assert (pairs.reference == 0.5).all()
    torch.testing.assert_close(pairs.candidate[:, 0, 0, 0], torch.tensor([1.0] * 5 + [0.0] * 5))  # real, then coarse
    torch.testing.assert_close(pairs.target, torch.tensor([1.0] * 5 + [0.0] * 5))
    with pytest.raises(ValueError, match="pairing: expected one of"):
        sample_pairs(_batch(2), torch.Generator(), "balanced")


def test_pairs_are_seeded():
    a = sample_pairs(_batch(64), torch.Generator().manual_seed(3), "paper")
    b = sample_pairs(_batch(64), torch.Generator().manual_seed(3), "paper")
    c = sample_pairs(_batch(64), torch.Generator().manual_seed(4), "paper")
    assert torch.equal(a.target, b.target) and torch.equal(a.candidate, b.candidate)
    assert not torch.equal(a.target, c.target)


def test_bad_batch_names_the_field():
    good = _batch(2)
    rng = torch.Generator().manual_seed(0)
    with pytest.raises(ValueError, match=r"coarse: shape \[2, 3, 4, 5\] differs from gt's \[2, 3, 4, 4\]"):
        sample_pairs(good._replace(coarse=torch.zeros(2, 3, 4, 5)), rng)
    with pytest.raises(ValueError, match=r"reference: expected shape \[B, 3, H, W\]"):
        sample_pairs(good._replace(reference=torch.zeros(2, 4, 4)), rng)
    with pytest.raises(ValueError, match="gt: expected a float tensor"):
        sample_pairs(good._replace(gt=torch.zeros(2, 3, 4, 4, dtype=torch.uint8)), rng)
