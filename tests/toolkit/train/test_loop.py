"""Training and evaluation on a tiny synthetic subject: the loss goes down, resume is exact, reports exist."""

import csv
import dataclasses
import json

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("anny")

from trioman.toolkit.avatar.model import AvatarConfig  # noqa: E402
from trioman.toolkit.evaluate import evaluate, load_run  # noqa: E402
from trioman.toolkit.synth.subject import SynthConfig, synthesize_subject  # noqa: E402
from trioman.toolkit.train.checkpoint import list_checkpoints, load_checkpoint  # noqa: E402
from trioman.toolkit.train.config import TrainConfig, preset  # noqa: E402
from trioman.toolkit.train.loop import train  # noqa: E402

TINY_AVATAR = AvatarConfig(keep=0.3, triplane_channels=4, triplane_res=16, hidden=32)


@pytest.fixture(scope="module")
def subject(tmp_path_factory):
    out = tmp_path_factory.mktemp("subj") / "s"
    synthesize_subject(SynthConfig(seed=5, size=32, frames=10, texture_size=256), out, progress=False)
    return out


def losses(run) -> np.ndarray:
    with open(run / "train_log.csv") as f:
        return np.array([float(r["loss"]) for r in csv.DictReader(f)])


def test_training_lowers_the_loss(subject, tmp_path):
    cfg = TrainConfig(iterations=60, lr=1e-2, random_background=False, checkpoint_every=60, avatar=TINY_AVATAR)
    run = train(subject, tmp_path / "run", cfg, progress=False)
    loss = losses(run)
    assert len(loss) == 60 and np.all(np.isfinite(loss))
    assert loss[-10:].mean() < 0.8 * loss[:10].mean(), (loss[:10].mean(), loss[-10:].mean())
    saved = json.loads((run / "config.json").read_text())
    assert TrainConfig.from_dict(saved["train"]) == cfg and saved["subject"] == str(subject.resolve())


def test_resume_after_interruption_matches_an_uninterrupted_run(subject, tmp_path):
    cfg = TrainConfig(iterations=6, checkpoint_every=3, avatar=TINY_AVATAR)
    straight = train(subject, tmp_path / "a", cfg, progress=False)
    broken = train(subject, tmp_path / "b", cfg, progress=False, stop_after=4)  # killed after step 4
    assert [p.name for p in list_checkpoints(broken)] == ["ckpt_0000003.pt"]
    train(subject, broken, cfg, resume=True, progress=False)
    a, b = load_checkpoint(list_checkpoints(straight)[-1]), load_checkpoint(list_checkpoints(broken)[-1])
    assert a["step"] == b["step"] == 6
    for key in a["model"]:
        torch.testing.assert_close(a["model"][key], b["model"][key], rtol=0, atol=1e-6)
    np.testing.assert_allclose(losses(straight), losses(broken), atol=1e-6)  # the log was trimmed and rewritten
    assert not list((broken / "checkpoints").glob(".*")), "no temporary files left behind"


def test_point_colours_train_at_their_own_decaying_learning_rate(subject, tmp_path):
    avatar = dataclasses.replace(TINY_AVATAR, point_colors=True)
    cfg = TrainConfig(iterations=4, checkpoint_every=4, lr=1e-3, point_color_lr=5e-2, lr_decay_at=(0.5, 0.9), avatar=avatar)
    state = load_checkpoint(list_checkpoints(train(subject, tmp_path / "p", cfg, progress=False))[-1])
    groups = state["optimizer"]["param_groups"]
    assert [len(g["params"]) for g in groups][1] == 1  # point_rgb alone
    assert groups[0]["lr"] == pytest.approx(1e-4) and groups[1]["lr"] == pytest.approx(5e-3)  # step 3: x0.1
    assert state["model"]["point_rgb"].shape == (load_run(tmp_path / "p")[0].num_gaussians, 3)
    assert state["model"]["point_rgb"].abs().max() > 1e-3


def test_refuses_to_overwrite_a_run_and_reports_bad_checkpoints(subject, tmp_path):
    cfg = TrainConfig(iterations=2, checkpoint_every=2, avatar=TINY_AVATAR)
    run = train(subject, tmp_path / "r", cfg, progress=False)
    with pytest.raises(FileExistsError, match="--resume"):
        train(subject, run, cfg, progress=False)
    ckpt = list_checkpoints(run)[-1]
    ckpt.write_bytes(ckpt.read_bytes()[:100])  # truncated
    with pytest.raises(ValueError, match="not a readable checkpoint"):
        load_checkpoint(ckpt)


def test_evaluate_writes_every_report(subject, tmp_path):
    cfg = TrainConfig(iterations=3, checkpoint_every=3, avatar=TINY_AVATAR)
    run = train(subject, tmp_path / "e", cfg, progress=False)
    summary = evaluate(run, "test", progress=False)
    out = run / "eval_test"
    for name in ("metrics.csv", "summary.json", "report.md", "grid.png", "video.mp4"):
        assert (out / name).stat().st_size > 0, name
    assert summary["frames"] == 4 and summary["lpips"].startswith("not computed")
    assert np.isfinite(summary["mean"]["psnr"]) and 0 < summary["mean"]["ssim"] <= 1
    # The masked protocol puts both images on white with the GT mask: it can only agree more than unmasked.
    assert summary["mean"]["psnr"] >= summary["mean"]["psnr_unmasked"] - 1e-6
    model, _, _, step = load_run(run)
    assert step == 3 and model.num_gaussians > 0


def test_presets_and_bad_values():
    assert preset("quick").iterations < preset("full").iterations
    with pytest.raises(ValueError, match="preset: unknown preset 'fast'"):
        preset("fast")
    with pytest.raises(ValueError, match="iterations"):
        TrainConfig(iterations=0)
    with pytest.raises(ValueError, match="image_scale"):
        TrainConfig(image_scale=2.0)
    with pytest.raises(ValueError, match="point_color_lr: must be > 0, got 0"):
        TrainConfig(point_color_lr=0)


def test_training_leaves_the_subnormal_setting_as_it_found_it(subject, tmp_path):
    from trioman.toolkit.cpu import denormals_flushed

    assert not denormals_flushed()
    train(subject, tmp_path / "d", TrainConfig(iterations=1, checkpoint_every=1, avatar=TINY_AVATAR), progress=False)
    assert not denormals_flushed()
