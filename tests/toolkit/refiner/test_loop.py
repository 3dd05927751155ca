"""Refiner loss, batches, training loop and checkpoints."""

from __future__ import annotations

import dataclasses

import pytest
import torch

from tests.toolkit.refiner.helpers import synthetic_batch, tiny_config
from trioman.toolkit.lpips import LPIPS
from trioman.toolkit.refiner import (
    RefinerLossWeights,
    RefinerTrainConfig,
    check_batch,
    create_refiner,
    load_refiner,
    refiner_inputs,
    refiner_loop,
    refiner_loss,
    refiner_targets,
)
from trioman.toolkit.loops.checkpoint import latest_checkpoint


def test_loss_is_zero_on_targets_and_names_its_terms():
    g = torch.Generator().manual_seed(0)
    targets = torch.rand(2, 3, 3, 32, 32, generator=g)
    total, terms = refiner_loss(targets, targets)
    assert set(terms) == {"l1", "ssim"} and total.abs() < 1e-6
    outputs = torch.rand(2, 3, 3, 32, 32, generator=g, requires_grad=True)
    total, terms = refiner_loss(outputs, targets, lpips=LPIPS(), weights=RefinerLossWeights(l1=1, ssim=0.5, lpips=2))
    assert set(terms) == {"l1", "ssim", "lpips"}
    assert torch.allclose(total, terms["l1"] + 0.5 * terms["ssim"] + 2 * terms["lpips"])
    total.backward()
    assert torch.isfinite(outputs.grad).all() and outputs.grad.abs().sum() > 0


def test_loss_errors_name_the_argument():
    x = torch.rand(2, 3, 3, 32, 32)
    with pytest.raises(ValueError, match="outputs"):
        refiner_loss(x[:, 0], x[:, 0])
    with pytest.raises(ValueError, match="targets"):
        refiner_loss(x, x[:, :2])
    with pytest.raises(ValueError, match="ssim"):
        RefinerLossWeights(ssim=-1)


def test_batch_to_inputs_and_targets():
    b = synthetic_batch(0, batch=2)
    assert refiner_inputs(b, "tex") == (b.coarse, b.reference)
    t = refiner_targets(b, "tex+geo")
    assert t.shape == (2, 3, 3, 32, 32)
    assert torch.equal(t[:, 0], b.target) and torch.equal(t[:, 1], b.reference_target) and torch.equal(t[:, 2], b.normal)
    with pytest.raises(ValueError, match="conditions"):
        refiner_targets(b, "all")
    aligned = b._replace(aligned=torch.rand_like(b.coarse))
    check_batch(aligned)
    assert refiner_inputs(aligned, "warp+geo") == (b.coarse, aligned.aligned, b.normal)
    t = refiner_targets(aligned, "warp+geo")  # views (aligned, coarse, normal): both image views learn I^T
    assert torch.equal(t[:, 0], b.target) and torch.equal(t[:, 1], b.target) and torch.equal(t[:, 2], b.normal)
    with pytest.raises(ValueError, match="aligned: shape"):
        check_batch(aligned._replace(aligned=b.coarse[..., :16]))
    with pytest.raises(ValueError, match="normal: shape"):
        check_batch(b._replace(normal=b.normal[..., :16]))
    with pytest.raises(ValueError, match="target: contains NaN"):
        check_batch(b._replace(target=torch.full_like(b.target, float("nan"))))


def test_training_lowers_the_loss():
    model = create_refiner(tiny_config())
    result = refiner_loop(model, synthetic_batch, RefinerTrainConfig(steps=30, lr=3e-3))
    first, last = sum(result.losses[:5]) / 5, sum(result.losses[-5:]) / 5
    assert result.step == 30 and not model.training
    assert last < 0.9 * first, result.losses


def test_checkpoint_round_trip_resume_and_determinism(tmp_path):
    config = RefinerTrainConfig(steps=3, lr=1e-3, checkpoint_every=2, keep_checkpoints=1)
    batches = lambda step: synthetic_batch(step, batch=2)  # noqa: E731
    straight = create_refiner(tiny_config(conditions="tex"), seed=7)
    reference = refiner_loop(straight, batches, config)

    model = create_refiner(tiny_config(conditions="tex"), seed=7)
    first = refiner_loop(model, batches, dataclasses.replace(config, steps=2), run=tmp_path)
    assert first.checkpoint == latest_checkpoint(tmp_path) and first.step == 2
    resumed = refiner_loop(create_refiner(tiny_config(conditions="tex"), seed=0), batches, config, run=tmp_path)
    assert resumed.step == 3 and first.losses + resumed.losses == pytest.approx(reference.losses, abs=1e-6)

    state = torch.load(resumed.checkpoint, weights_only=True)
    assert state["step"] == 3 and state["config"] == tiny_config(conditions="tex").to_dict()
    loaded = load_refiner(resumed.checkpoint, exportable=True)
    x = refiner_inputs(synthetic_batch(9, batch=2), "tex")
    with torch.no_grad():
        assert torch.allclose(loaded(*x), straight.eval()(*x), atol=1e-5)

    with pytest.raises(ValueError, match="differs"):
        refiner_loop(create_refiner(tiny_config()), batches, config, run=tmp_path)


def _poison_output(model, steps: set[int], counter: list[int]):
    """A forward hook that makes the model's output NaN on the given calls (0-based)."""

    def hook(module, inputs, output):
        counter[0] += 1
        return output * float("nan") if counter[0] - 1 in steps else output

    return model.register_forward_hook(hook)


def test_non_finite_steps_are_skipped_and_counted(tmp_path):
    model = create_refiner(tiny_config(), seed=0)
    _poison_output(model, {2, 3}, [0])
    config = RefinerTrainConfig(steps=6, lr=1e-3, checkpoint_every=3)
    result = refiner_loop(model, synthetic_batch, config, run=tmp_path)
    assert result.step == 6 and result.skipped == 2 and len(result.losses) == 4
    assert all(torch.isfinite(p).all() for p in model.parameters())
    assert torch.load(result.checkpoint, weights_only=True)["skipped"] == 2


def test_repeated_non_finite_steps_stop_and_keep_the_last_good_checkpoint(tmp_path):
    model = create_refiner(tiny_config(), seed=0)
    _poison_output(model, set(range(2, 100)), [0])
    config = RefinerTrainConfig(steps=10, lr=1e-3, checkpoint_every=2, max_skipped=3)
    with pytest.raises(FloatingPointError, match="refiner: 3 consecutive steps .* the run stops.*Lower the learning rate"):
        refiner_loop(model, synthetic_batch, config, run=tmp_path)
    assert latest_checkpoint(tmp_path).name == "ckpt_0000004.pt"  # steps 3, 4 skipped (weights unchanged, saved)


def test_non_finite_weights_are_never_saved(tmp_path):
    model = create_refiner(tiny_config(), seed=0)

    def batches(step):
        if step == 2:
            with torch.no_grad():
                next(model.parameters()).fill_(float("inf"))
        return synthetic_batch(step)

    with pytest.raises(FloatingPointError, match="weights at step 4 are not finite.*ckpt_0000002.pt"):
        refiner_loop(model, batches, RefinerTrainConfig(steps=6, lr=1e-3, checkpoint_every=2), run=tmp_path)
    assert latest_checkpoint(tmp_path).name == "ckpt_0000002.pt"
