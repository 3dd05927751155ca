"""Pose corrections learnt with the avatar (--refine-poses): the knots' interpolation against a brute-force
reference, training and resume with them, and evaluation at the corrected poses."""

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("anny")

from tests.toolkit.train.factories import TINY_AVATAR  # noqa: E402
from trioman.runtime.formats import load_subject, save_subject  # noqa: E402
from trioman.toolkit.evaluate import evaluate, run_poses  # noqa: E402
from trioman.toolkit.loops.checkpoint import list_checkpoints, load_checkpoint  # noqa: E402
from trioman.toolkit.synth.subject import SynthConfig, synthesize_subject  # noqa: E402
from trioman.toolkit.train.augment_config import AugmentConfig  # noqa: E402
from trioman.toolkit.train.config import FITTED_BY, TrainConfig, with_subject_defaults  # noqa: E402
from trioman.toolkit.train.loop import train  # noqa: E402
from trioman.toolkit.train.pose_corrections import PoseCorrections  # noqa: E402


def brute_force(sequence: np.ndarray, knot_every: int, values: np.ndarray) -> np.ndarray:
    """Frame i's correction: the linear interpolation, over its position in its sequence, of the knot values
    (knots at positions 0, k, 2k, ... and the last), knots numbered sequence after sequence -> [F, ...]."""
    out, first = np.zeros((len(sequence), *values.shape[1:])), 0
    for name in dict.fromkeys(sequence.tolist()):
        frames = np.flatnonzero(sequence == name)
        at = sorted(set(range(0, len(frames), knot_every)) | {len(frames) - 1})
        for pos, f in enumerate(frames):
            for axis in np.ndindex(values.shape[1:]):
                out[(f, *axis)] = np.interp(pos, at, values[(slice(first, first + len(at)), *axis)])
        first += len(at)
    return out


@pytest.mark.parametrize("knot_every", [1, 3, 4, 50])
def test_corrections_interpolate_their_knots_within_each_sequence(knot_every):
    sequence = np.array(["a"] * 11 + ["b"] * 1 + ["c"] * 6)
    c = PoseCorrections(sequence, joints=2, knot_every=knot_every)
    gen = torch.Generator().manual_seed(0)
    with torch.no_grad():
        c.pose.copy_(torch.randn(c.pose.shape, generator=gen))
        c.trans.copy_(torch.randn(c.trans.shape, generator=gen))
    expect_pose = brute_force(sequence, knot_every, c.pose.detach().double().numpy())
    expect_trans = brute_force(sequence, knot_every, c.trans.detach().double().numpy())
    got = [c(i) for i in range(len(sequence))]
    np.testing.assert_allclose(np.stack([g[0].detach().numpy() for g in got]), expect_pose, atol=1e-6)
    np.testing.assert_allclose(np.stack([g[1].detach().numpy() for g in got]), expect_trans, atol=1e-6)
    poses, trans = np.ones((len(sequence), 2, 3)), np.zeros((len(sequence), 3))
    all_p, all_t = c.all(poses, trans)
    np.testing.assert_allclose(all_p, expect_pose + 1, atol=1e-6)
    np.testing.assert_allclose(all_t, expect_trans, atol=1e-6)
    with pytest.raises(ValueError, match="knot_every: must be >= 1, got 0"):
        PoseCorrections(sequence, 2, 0)


def test_zero_corrections_change_nothing_and_cost_nothing():
    c = PoseCorrections(np.array(["a"] * 5), joints=3, knot_every=2)
    pose, trans = torch.randn(3, 3), torch.randn(3)
    p, t = c.apply(4, pose, trans)
    assert torch.equal(p, pose) and torch.equal(t, trans) and float(c.penalty(4).detach()) == 0.0


@pytest.fixture(scope="module")
def noisy(tmp_path_factory):
    """A video-like subject with noisy poses: one sequence, every third frame held out (as trioman fit writes)."""
    root = tmp_path_factory.mktemp("noisy")
    synthesize_subject(SynthConfig(seed=5, size=32, frames=12, texture_size=256, pose_noise_deg=8.0), root / "synth",
                       progress=False)
    s, n = load_subject(root / "synth"), 12
    return save_subject(root / "s", body=s.body, poses=s.poses, trans=s.trans, K=s.K, viewmat=s.viewmat,
                        split=["test" if i % 3 == 1 else "train" for i in range(n)], sequence=["video"] * n,
                        images=(s.image(i) for i in range(n)), masks=(s.mask(i) for i in range(n)), width=s.width,
                        height=s.height, body_model=s.body_model, background=(0.0, 0.0, 0.0), poses_true=s.poses_true,
                        phenotype=s.meta["phenotype"], generator={"tool": "test"}).root


def test_training_learns_corrections_that_resume_exactly_and_evaluation_renders_at(noisy, tmp_path):
    cfg = TrainConfig(iterations=8, checkpoint_every=4, avatar=TINY_AVATAR, refine_poses=True, pose_knot_every=6)
    straight = train(noisy, tmp_path / "a", cfg, progress=False)
    broken = train(noisy, tmp_path / "b", cfg, progress=False, stop_after=5)
    train(noisy, broken, cfg, resume=True, progress=False)
    a, b = load_checkpoint(list_checkpoints(straight)[-1]), load_checkpoint(list_checkpoints(broken)[-1])
    for key in ("pose", "trans"):
        torch.testing.assert_close(a["pose_corrections"][key], b["pose_corrections"][key], rtol=0, atol=1e-6)
    learnt = a["pose_corrections"]["pose"]
    assert learnt.abs().max() > 0, "the corrections moved"
    subject = load_subject(noisy)
    poses, trans = run_poses(straight, subject)
    assert poses.shape == subject.poses.shape and trans.shape == subject.trans.shape
    test = subject.indices("test")
    assert np.abs(poses[test] - subject.poses[test]).max() > 0, "held-out frames take their neighbours' corrections"
    run = evaluate(straight, "test", tmp_path / "e_run", progress=False, video=False)
    stored = evaluate(straight, "test", tmp_path / "e_stored", progress=False, video=False, poses="stored")
    assert (run["poses"], stored["poses"]) == ("stored, corrected by the run", "stored")
    assert run["mean"]["psnr"] != stored["mean"]["psnr"]
    plain = train(noisy, tmp_path / "plain", TrainConfig(iterations=4, checkpoint_every=4, avatar=TINY_AVATAR), progress=False)
    assert run_poses(plain, subject) is None and "pose_corrections" not in load_checkpoint(list_checkpoints(plain)[-1])


def test_command_line_refine_poses(noisy, tmp_path, capsys):
    from trioman.cli import main

    assert main(["train", str(noisy), "--out", str(tmp_path / "r"), "--iterations", "2", "--refine-poses", "--quiet"]) == 0
    assert main(["eval", str(tmp_path / "r"), "--no-video", "--quiet"]) == 0
    assert "PSNR" in capsys.readouterr().out
    assert load_checkpoint(list_checkpoints(tmp_path / "r")[-1])["pose_corrections"]["pose"].abs().max() > 0


@pytest.mark.parametrize("given, tool, augment, resolved", [
    (None, FITTED_BY, None, True), (None, "trioman synth", None, False), (None, "trioman import exavatar", None, False),
    (None, FITTED_BY, AugmentConfig(mode="aligned"), False), (False, FITTED_BY, None, False),
    (True, "trioman synth", None, True)])
def test_pose_corrections_default_to_fitted_subjects(given, tool, augment, resolved):
    cfg = with_subject_defaults(TrainConfig(refine_poses=given, augment=augment), tool)
    assert cfg.refine_poses is resolved


def test_a_subject_of_trioman_fit_is_trained_with_corrections_unless_told(noisy, tmp_path):
    import dataclasses
    import json
    import shutil

    from trioman.toolkit.train.resume import resume_command

    fitted = tmp_path / "fitted"
    shutil.copytree(noisy, fitted)
    meta = json.loads((fitted / "subject.json").read_text())
    (fitted / "subject.json").write_text(json.dumps({**meta, "generator": {"tool": FITTED_BY}}))
    cfg = TrainConfig(iterations=4, checkpoint_every=4, avatar=TINY_AVATAR, pose_start=0.0)
    for name, subject, given, learnt in (("auto", fitted, None, True), ("off", fitted, False, False),
                                         ("synthetic", noisy, None, False)):
        run = train(subject, tmp_path / name, dataclasses.replace(cfg, refine_poses=given), progress=False)
        assert json.loads((run / "config.json").read_text())["train"]["refine_poses"] is learnt
        assert ("pose_corrections" in load_checkpoint(list_checkpoints(run)[-1])) is learnt
        # the run resumes from its record with the same call (the default resolved the same way)
        train(subject, run, dataclasses.replace(cfg, refine_poses=given), resume=True, progress=False)
        # its resume hint adds no flag the subject already implies
        assert "refine-poses" not in resume_command(run, json.loads((run / "config.json").read_text())) or given is False


@pytest.mark.parametrize("field, value", [("pose_start", 1.0), ("pose_start", -0.1), ("pose_knot_every", 0), ("pose_lr", 0.0)])
def test_bad_pose_settings_are_named(field, value):
    with pytest.raises(ValueError, match=f"^{field}: "):
        TrainConfig(**{field: value})
