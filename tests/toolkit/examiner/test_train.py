"""Training from scratch on a synthetic pair task; checkpoints and resume."""

from __future__ import annotations

import pytest
import torch

from tests.toolkit.examiner.helpers import TINY, synthetic_batch
from trioman.toolkit.examiner import ExaminerTrainConfig, auroc, create_examiner, load_examiner, train_examiner
from trioman.toolkit.train.checkpoint import list_checkpoints


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """300 Adam steps (~10 s on one core) on 20 fixed batches of 16 synthetic samples."""
    run = tmp_path_factory.mktemp("examiner_run")
    g = torch.Generator().manual_seed(1)
    data = [synthetic_batch(16, TINY.img_size, g) for _ in range(20)]
    model = create_examiner(TINY)
    result = train_examiner(model, data, ExaminerTrainConfig(steps=300, lr=1e-3, checkpoint_every=100), run=run)
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
    full = train_examiner(straight, data, ExaminerTrainConfig(steps=6, seed=2))
    again = fresh()
    train_examiner(again, data, ExaminerTrainConfig(steps=6, seed=2))
    for key, value in straight.state_dict().items():
        torch.testing.assert_close(again.state_dict()[key], value, rtol=0, atol=0)

    # 3 steps and a checkpoint, then a fresh start resumes for the other 3; with 3 batches the
    # restarted data lines up with the straight run, so the losses match it
    train_examiner(fresh(), data, ExaminerTrainConfig(steps=3, seed=2, checkpoint_every=3), run=tmp_path)
    second = train_examiner(create_examiner(TINY), data, ExaminerTrainConfig(steps=6, seed=2, checkpoint_every=3), run=tmp_path)
    assert second.step == 6
    assert second.losses == pytest.approx(full.losses[3:], rel=1e-5)
    with pytest.raises(ValueError, match="checkpoint config .* differs from the model's"):
        train_examiner(create_examiner(TINY, head_hidden=8), data, ExaminerTrainConfig(steps=6), run=tmp_path)


def test_bad_train_config_and_empty_data():
    with pytest.raises(ValueError, match="steps: must be >= 1"):
        ExaminerTrainConfig(steps=0)
    with pytest.raises(ValueError, match="lr: must be > 0"):
        ExaminerTrainConfig(lr=0.0)
    with pytest.raises(ValueError, match="data: yielded no batch"):
        train_examiner(create_examiner(TINY), [], ExaminerTrainConfig(steps=1))
