"""choose(): the higher-scoring candidate per sample, its score, the keep flags."""

from __future__ import annotations

import pytest
import torch

from tests.toolkit.examiner.helpers import TINY
from trioman.toolkit.examiner import choose, create_examiner


@pytest.fixture(scope="module")
def setup():
    torch.manual_seed(0)
    model = create_examiner(TINY).eval()
    g = torch.Generator().manual_seed(2)
    candidates = torch.rand(3, 4, 3, 32, 32, generator=g)
    real = torch.rand(4, 3, 32, 32, generator=g)
    return model, candidates, real


def test_choice_is_the_argmax_of_the_scores(setup):
    model, candidates, real = setup
    with torch.no_grad():
        scores = torch.stack([model(c, real) for c in candidates])  # [K, B]
    choice = choose(model, candidates, real)
    assert choice.index.dtype == torch.long and choice.index.shape == (4,)
    torch.testing.assert_close(choice.index, scores.argmax(dim=0))
    torch.testing.assert_close(choice.score, scores.max(dim=0).values)
    assert choice.keep.all()
    two = choose(model, (candidates[0], candidates[1]), real)
    torch.testing.assert_close(two.index, scores[:2].argmax(dim=0))


def test_threshold_sets_the_keep_flags(setup):
    model, candidates, real = setup
    choice = choose(model, candidates, real)
    cut = float(choice.score.median())
    assert torch.equal(choose(model, candidates, real, threshold=cut).keep, choice.score >= cut)
    assert not choose(model, candidates, real, threshold=1.0).keep.any()


def test_bad_inputs(setup):
    model, candidates, real = setup
    with pytest.raises(ValueError, match=r"candidates: expected shape \[K, 4, 3, 32, 32\]"):
        choose(model, candidates[:, :2], real)
    with pytest.raises(ValueError, match="threshold: must lie in"):
        choose(model, candidates, real, threshold=1.5)
    with pytest.raises(ValueError, match="real: expected shape"):
        choose(model, candidates, real[:, :1])
