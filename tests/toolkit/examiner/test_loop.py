"""Training from scratch on a synthetic pair task; checkpoints and resume."""

from __future__ import annotations

import pytest
import torch

from tests.toolkit.examiner.helpers import TINY, synthetic_batch
from trioman.toolkit.examiner import ExaminerTrainConfig, auroc, create_examiner, examiner_loop, load_examiner
from trioman.toolkit.loops.checkpoint import list_checkpoints


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """300 Adam steps (~10 s on one core) on 20 fixed batches of 16 synthetic samples."""
    run = tmp_path_factory.mktemp("examiner_run")
    g = torch.Generator().manual_seed(1)
    data = [synthetic_batch(16, TINY.img_size, g) for _ in range(20)]
    model = create_examiner(TINY)
    result = examiner_loop(model, data, ExaminerTrainConfig(steps=300, lr=1e-3, checkpoint_every=100), run=run)
    return model, result, run


def test_training_lowers_the_loss_and_separates_real_from_coarse(trained):
    model, result, _ = trained
    assert result.step == 300 and len(result.losses) == 300
    first, last = sum(result.losses[:50]) / 50, sum(result.losses[-50:]) / 50
    assert last < 0.5 * first
    held_out = synthetic_batch(128, TINY.img_size, torch.Generator().manual_seed(99))
    with torch.no_grad():
        real = model(held_out.gt, held_out.reference)
        coarse = model(held_out.coarse, held_out.reference)
    assert auroc(torch.cat([real, coarse]), torch.cat([torch.ones(128), torch.zeros(128)])) > 0.8


def test_checkpoints_are_weights_only_and_reload(trained):
    model, result, run = trained
    assert [p.name for p in list_checkpoints(run)] == ["ckpt_0000200.pt", "ckpt_0000300.pt"]
    state = torch.load(result.checkpoint, map_location="cpu", weights_only=True)
    assert state["step"] == 300 and state["config"] == TINY.to_dict()
    reloaded = load_examiner(result.checkpoint, exportable=True)
    c = torch.rand(2, 3, 32, 32, generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        torch.testing.assert_close(reloaded(c, c.flip(0)), model(c, c.flip(0)), atol=1e-6, rtol=1e-5)


def test_resume_continues_from_the_checkpoint_and_is_seeded(tmp_path):
    g = torch.Generator().manual_seed(5)
    data = [synthetic_batch(4, TINY.img_size, g) for _ in range(3)]

    def fresh():
        torch.manual_seed(0)
        return create_examiner(TINY)

    straight = fresh()
    full = examiner_loop(straight, data, ExaminerTrainConfig(steps=6, seed=2))
    again = fresh()
    examiner_loop(again, data, ExaminerTrainConfig(steps=6, seed=2))
    for key, value in straight.state_dict().items():
        torch.testing.assert_close(again.state_dict()[key], value, rtol=0, atol=0)

    # 3 steps and a checkpoint, then a fresh start resumes for the other 3; with 3 batches the
    # restarted data lines up with the straight run, so the losses match it
    examiner_loop(fresh(), data, ExaminerTrainConfig(steps=3, seed=2, checkpoint_every=3), run=tmp_path)
    second = examiner_loop(create_examiner(TINY), data, ExaminerTrainConfig(steps=6, seed=2, checkpoint_every=3), run=tmp_path)
    assert second.step == 6
    assert second.losses == pytest.approx(full.losses[3:], rel=1e-5)
    with pytest.raises(ValueError, match=r"the run's Examiner differs from this one \(head_hidden: \d+ -> 8\); "):
        examiner_loop(create_examiner(TINY, head_hidden=8), data, ExaminerTrainConfig(steps=6), run=tmp_path)


def test_bad_train_config_and_empty_data():
    with pytest.raises(ValueError, match="steps: must be >= 1"):
        ExaminerTrainConfig(steps=0)
    with pytest.raises(ValueError, match="lr: must be > 0"):
        ExaminerTrainConfig(lr=0.0)
    with pytest.raises(ValueError, match="data: yielded no batch"):
        examiner_loop(create_examiner(TINY), [], ExaminerTrainConfig(steps=1))


def test_validation_keeps_the_first_best_step_and_survives_a_resume(tmp_path):
    """validate runs every checkpoint_every steps; the model ends with the weights of the first step
    of the highest value (run/selected.pt holds them), and a resumed run selects the same step."""
    from trioman.toolkit.loops.checkpoint import load_checkpoint, model_checkpoint

    g = torch.Generator().manual_seed(5)
    data = [synthetic_batch(4, TINY.img_size, g) for _ in range(2)]
    values = iter([0.6, 0.9, 0.7, 0.9])  # steps 2, 4, 6, 8: step 4 is the first best

    def fresh():
        torch.manual_seed(0)
        return create_examiner(TINY)

    cfg = ExaminerTrainConfig(steps=8, seed=2, checkpoint_every=2)
    model = fresh()
    result = examiner_loop(model, data, cfg, run=tmp_path / "a", validate=lambda m: next(values))
    assert result.selected_step == 4 and result.validation == {2: 0.6, 4: 0.9, 6: 0.7, 8: 0.9}
    assert result.selected == tmp_path / "a" / "selected.pt" == model_checkpoint(tmp_path / "a")
    at_four = fresh()
    examiner_loop(at_four, data, ExaminerTrainConfig(steps=4, seed=2))  # validation changes no training step
    for key, value in at_four.state_dict().items():
        torch.testing.assert_close(model.state_dict()[key], value, rtol=0, atol=0)
        torch.testing.assert_close(load_checkpoint(result.selected)["model"][key], value, rtol=0, atol=0)
    assert not model.training

    # stopped after step 6, resumed to 8: same record, same selection
    values = iter([0.6, 0.9, 0.7, 0.9])
    examiner_loop(fresh(), data, ExaminerTrainConfig(steps=6, seed=2, checkpoint_every=2), run=tmp_path / "b",
                   validate=lambda m: next(values))
    resumed = fresh()
    again = examiner_loop(resumed, data, cfg, run=tmp_path / "b", validate=lambda m: next(values))
    assert again.selected_step == 4 and again.validation == result.validation
    for key, value in model.state_dict().items():
        torch.testing.assert_close(resumed.state_dict()[key], value, rtol=0, atol=0)
    with pytest.raises(ValueError, match="validate: returned NaN"):
        examiner_loop(fresh(), data, ExaminerTrainConfig(steps=2, checkpoint_every=2), validate=lambda m: float("nan"))


def test_non_finite_gradients_are_skipped_and_repeated_ones_stop(tmp_path):
    g = torch.Generator().manual_seed(1)
    data = [synthetic_batch(4, TINY.img_size, g) for _ in range(2)]
    model = create_examiner(TINY)
    calls, bad = [0], {1, 2}  # NaN gradients on these backward calls (0-based); None: on every call
    seen = []  # the weights at each backward call, before its step's update

    def poison(grad):
        calls[0] += 1
        seen.append([p.detach().clone() for p in model.parameters()])
        return grad * float("nan") if bad is None or calls[0] - 1 in bad else grad

    next(model.parameters()).register_hook(poison)
    result = examiner_loop(model, data, ExaminerTrainConfig(steps=5, lr=1e-3, checkpoint_every=5), run=tmp_path)
    assert result.skipped == 2 and len(result.losses) == 3 and result.step == 5
    same = [all(torch.equal(a, b) for a, b in zip(seen[i], seen[i + 1])) for i in range(4)]
    assert same == [False, True, True, False]  # the skipped steps 1 and 2 left the weights as they were
    assert torch.load(result.checkpoint, weights_only=True)["skipped"] == 2
    bad = None
    with pytest.raises(FloatingPointError, match="examiner: 2 consecutive steps"):
        examiner_loop(model, data, ExaminerTrainConfig(steps=9, lr=1e-3, checkpoint_every=5, max_skipped=2), run=tmp_path)
    assert [p.name for p in list_checkpoints(tmp_path)] == ["ckpt_0000005.pt"]
