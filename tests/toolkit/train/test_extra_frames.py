"""``trioman train --extra-frames DIR``: pseudo-GT frames sampled with the subject's frames, recorded, checked, resumable."""

import csv
import dataclasses
import json

import cv2
import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("anny")

from tests.toolkit.avatar.factories import grid_mesh  # noqa: E402
from trioman.cli import main  # noqa: E402
from trioman.runtime.formats import load_subject, save_subject  # noqa: E402
from trioman.toolkit.avatar.model import AvatarConfig  # noqa: E402
from trioman.toolkit.synth.subject import SynthConfig, synthesize_subject  # noqa: E402
from trioman.toolkit.loops.checkpoint import list_checkpoints, load_checkpoint  # noqa: E402
from trioman.toolkit.train.config import TrainConfig  # noqa: E402
from trioman.toolkit.train.data import join_frames, load_frames  # noqa: E402
from trioman.toolkit.train.loop import train  # noqa: E402

TINY_AVATAR = AvatarConfig(keep=0.05, triplane_channels=4, triplane_res=8, hidden=8)


def pseudo_subject(src, out, frames=(0, 1, 2), size=None, body=None):
    """A stand-in for `trioman augment` output: some of ``src``'s frames with a turned camera, all "train"."""
    s = load_subject(src)
    idx = list(frames)
    W, H = size or (s.width, s.height)

    def resized(img):
        return img if (W, H) == (s.width, s.height) else cv2.resize(img, (W, H), interpolation=cv2.INTER_AREA)

    J = (body or s.body).skeleton.num_joints
    poses = np.array(s.poses[idx]) if body is None else np.zeros((len(idx), J, 3), np.float32)
    return save_subject(
        out, body=body or s.body, poses=poses, trans=np.array(s.trans[idx]), K=np.array(s.K[idx]),
        viewmat=np.array(s.viewmat[idx]), split=["train"] * len(idx), sequence=[s.sequence[i] for i in idx],
        images=(resized(s.image(i)[::-1].copy()) for i in idx), masks=(resized(s.mask(i)[::-1].copy()) for i in idx),
        width=W, height=H, body_model=s.body_model, background=s.background.tolist(),
        frame_names=[f"{s.frame_names[i]}_c0" for i in idx],
    ).root


@pytest.fixture(scope="module")
def subjects(tmp_path_factory):
    root = tmp_path_factory.mktemp("extra")
    synthesize_subject(SynthConfig(seed=5, size=32, frames=6, texture_size=64), root / "s", progress=False)
    return root / "s", pseudo_subject(root / "s", root / "aug")


def log(run) -> list[dict]:
    with open(run / "train_log.csv") as f:
        return list(csv.DictReader(f))


def test_frames_are_joined_with_their_weights(subjects):
    s, aug = load_subject(subjects[0]), load_subject(subjects[1])
    a, b = load_frames(s, "train"), load_frames(aug, None)
    j = join_frames(a, b, 0.25)
    assert len(j) == len(a) + len(b) and j.weights.tolist() == [1.0] * len(a) + [0.25] * len(b)
    for k in range(len(b)):
        torch.testing.assert_close(j.sample(len(a) + k)["images"], b.image(k), rtol=0, atol=0)
    torch.testing.assert_close(j.viewmat[: len(a)], a.viewmat, rtol=0, atol=0)


def test_training_with_extra_frames_runs_and_records_them(subjects, tmp_path):
    subject, aug = subjects
    n_real, n_extra = len(load_subject(subject).indices("train")), load_subject(aug).num_frames
    # A seed whose first draw (uniform over the union) is a pseudo-GT frame.
    seed = next(s for s in range(100) if np.random.default_rng(s).integers(n_real + n_extra) >= n_real)
    cfg = TrainConfig(iterations=3, checkpoint_every=3, avatar=TINY_AVATAR, extra_frames=str(aug), extra_weight=0.5,
                      seed=seed, random_background=False)
    run = train(subject, tmp_path / "run", cfg, progress=False)
    saved = json.loads((run / "config.json").read_text())
    assert saved["train"]["extra_frames"] == str(aug) and saved["train"]["extra_weight"] == 0.5
    # the record holds the config as trained: the subject-dependent defaults resolved (a synthetic subject: no pose
    # corrections)
    assert TrainConfig.from_dict(saved["train"]) == dataclasses.replace(cfg, refine_poses=False)
    assert len(log(run)) == 3 and all(np.isfinite(float(r["loss"])) for r in log(run))
    # The first step trained on a pseudo-GT frame: its loss scales with extra_weight (0: regularisers only).
    losses = {}
    for w in (0.0, 1.0):
        one = dataclasses.replace(cfg, extra_weight=w, iterations=1, checkpoint_every=1)
        r = train(subject, tmp_path / f"w{w}", one, progress=False)
        losses[w] = float(log(r)[0]["loss"])
    first = float(log(run)[0]["loss"])
    assert losses[0.0] < first < losses[1.0]
    assert first == pytest.approx(0.5 * (losses[0.0] + losses[1.0]), abs=2e-6)


def test_command_line_records_the_resolved_path(subjects, tmp_path, monkeypatch):
    subject, aug = subjects
    monkeypatch.chdir(aug.parent)
    out = tmp_path / "cli"
    assert main(["train", str(subject), "--out", str(out), "--iterations", "1", "--quiet",
                 "--extra-frames", aug.name, "--extra-weight", "2"]) == 0
    saved = json.loads((out / "config.json").read_text())["train"]
    assert saved["extra_frames"] == str(aug.resolve()) and saved["extra_weight"] == 2.0
    assert main(["train", str(subject), "--out", str(tmp_path / "x"), "--extra-frames", str(tmp_path / "nope")]) == 1
    assert main(["train", str(subject), "--out", str(tmp_path / "y"), "--extra-weight", "2"]) == 1


def test_mismatched_extra_subjects_are_refused_before_the_run_is_written(subjects, tmp_path):
    subject, _ = subjects
    small = pseudo_subject(subject, tmp_path / "small", size=(16, 16))
    other = pseudo_subject(subject, tmp_path / "other", body=grid_mesh())
    for extra, match in ((small, r"16x16 \(W x H\) images, but the subject .* has 32x32"),
                         (other, r"body of 4 joints that differs from the subject's \(\d+ joints\)")):
        cfg = TrainConfig(iterations=1, checkpoint_every=1, avatar=TINY_AVATAR, extra_frames=str(extra))
        with pytest.raises(ValueError, match=match):
            train(subject, tmp_path / f"run_{extra.name}", cfg, progress=False)
        assert not (tmp_path / f"run_{extra.name}" / "config.json").exists()
    with pytest.raises(ValueError, match="extra_weight: must be a finite number >= 0, got -1"):
        TrainConfig(extra_weight=-1)
    with pytest.raises(ValueError, match="extra_weight"):
        TrainConfig(extra_weight=float("nan"))


def test_resume_with_extra_frames_matches_an_uninterrupted_run(subjects, tmp_path):
    subject, aug = subjects
    cfg = TrainConfig(iterations=6, checkpoint_every=3, avatar=TINY_AVATAR, extra_frames=str(aug), extra_weight=0.7)
    straight = train(subject, tmp_path / "a", cfg, progress=False)
    broken = train(subject, tmp_path / "b", cfg, progress=False, stop_after=4)
    with pytest.raises(ValueError, match=r"the training config differs from the run's \(checkpoint_every: 3 -> 250; "
                                         r"extra_frames: .* -> None; extra_weight: 0\.7 -> 1\.0\)"):
        train(subject, broken, TrainConfig(iterations=6, avatar=TINY_AVATAR), resume=True, progress=False)
    train(subject, broken, cfg, resume=True, progress=False)
    a, b = load_checkpoint(list_checkpoints(straight)[-1]), load_checkpoint(list_checkpoints(broken)[-1])
    assert a["step"] == b["step"] == 6
    for key in a["model"]:
        torch.testing.assert_close(a["model"][key], b["model"][key], rtol=0, atol=1e-6)
    np.testing.assert_allclose([float(r["loss"]) for r in log(straight)], [float(r["loss"]) for r in log(broken)], atol=1e-6)


def test_per_pixel_weights_of_extra_frames_reach_the_loss(subjects, tmp_path):
    """A subject folder with weights/ (trioman augment without a Refiner): every frame's weights come with its
    sample, held in memory or read from disk alike; a weight 0 pixel does not change the loss."""
    import shutil

    from trioman.runtime.image_io import write_png
    from trioman.toolkit.train.config import TrainConfig as TC
    from trioman.toolkit.train.loop import photometric

    aug = tmp_path / "weighted"
    shutil.copytree(subjects[1], aug)
    s = load_subject(aug)
    (aug / "weights").mkdir()
    half = np.zeros((s.height, s.width), np.float32)
    half[:, : s.width // 2] = 1.0
    for name in s.frame_names:
        write_png(aug / "weights" / f"{name}.png", half)
    mem, disk = load_frames(s, None), load_frames(s, None, in_memory_bytes=0)
    for frames in (mem, disk):
        w = frames.sample(0)["pixel_weights"]
        torch.testing.assert_close(w, torch.from_numpy(half), rtol=0, atol=0)
    assert "pixel_weights" not in load_frames(load_subject(subjects[1]), None).sample(0)
    pred, gt = torch.rand(s.height, s.width, 3), torch.rand(s.height, s.width, 3)
    changed = gt.clone()
    changed[:, s.width // 2:] = 1 - changed[:, s.width // 2:]  # only where the weight is 0
    cfg, w = TC(), torch.from_numpy(half)
    assert float(photometric(pred, gt, cfg, pixel_weights=torch.ones_like(w))) == pytest.approx(float(photometric(pred, gt, cfg)))
    l1_only = dataclasses.replace(cfg, weights=dataclasses.replace(cfg.weights, ssim=0.0))
    assert float(photometric(pred, gt, l1_only, pixel_weights=w)) == pytest.approx(float(photometric(pred, changed, l1_only, pixel_weights=w)))
    run = train(subjects[0], tmp_path / "run", TrainConfig(iterations=4, checkpoint_every=4, avatar=TINY_AVATAR,
                                                          extra_frames=str(aug)), progress=False)
    assert len(log(run)) == 4 and all(np.isfinite(float(r["loss"])) for r in log(run))
    (aug / "weights" / f"{s.frame_names[1]}.png").unlink()
    with pytest.raises(Exception, match="weights.*missing file"):
        load_frames(s, None)
