"""The non-finite guard of the training loops (toolkit.loops.guard)."""

from __future__ import annotations

import pytest
import torch

from trioman.toolkit.loops.guard import NonFiniteError, StepGuard, check_weights, grads_finite, weights_finite


def test_guard_skips_and_counts_and_stops_after_consecutive_failures():
    guard = StepGuard("model", max_consecutive=3)
    p = torch.nn.Parameter(torch.ones(2))
    assert guard.finite_ok(torch.tensor(1.0), 0)
    assert not guard.finite_ok(torch.tensor([0.0, float("nan")]), 1, "output")
    p.grad = torch.tensor([1.0, float("inf")])
    assert not guard.grads_ok([p], 2)
    p.grad = torch.ones(2)
    assert guard.grads_ok([p], 3) and guard.consecutive == 0 and guard.skipped == 2  # a good step resets the run
    for step in (4, 5):
        assert not guard.finite_ok(torch.tensor(float("inf")), step)
    with pytest.raises(NonFiniteError, match=r"model: 3 consecutive steps \(the last, step 7, with a non-finite loss\).*5 skipped in all"):
        guard.finite_ok(torch.tensor(float("inf")), 6, hint="Lower the learning rate.")


def test_finiteness_of_gradients_and_weights():
    m = torch.nn.Linear(2, 2)
    assert grads_finite(m.parameters()) and weights_finite(m)  # no gradients yet
    with torch.no_grad():
        m.weight[0, 0] = float("nan")
    assert not weights_finite(m)
    with pytest.raises(NonFiniteError, match="step 4 are not finite.*the last good checkpoint is ckpt_2.pt"):
        check_weights(m, "model", 4, "ckpt_2.pt")
    with pytest.raises(ValueError, match="max_consecutive"):
        StepGuard("model", 0)
