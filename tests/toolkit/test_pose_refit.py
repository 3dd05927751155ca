"""Test-time pose refitting (trioman eval --poses optimised): a known root shift found with the avatar left as it
was, a non-finite loss keeping the pose, the settings' errors, and the evaluation and command that use it."""

import json

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("anny")

from tests.toolkit.train.factories import TINY_AVATAR  # noqa: E402
from trioman.runtime.formats import load_subject, save_subject  # noqa: E402
from trioman.toolkit.avatar.model import GaussianAvatar  # noqa: E402
from trioman.toolkit.evaluate import evaluate  # noqa: E402
from trioman.toolkit.pose_refit import RefitSettings, _minimise, refit_poses  # noqa: E402
from trioman.toolkit.render import rasterize  # noqa: E402
from trioman.toolkit.synth.subject import SynthConfig, synthesize_subject  # noqa: E402
from trioman.toolkit.train.config import TrainConfig  # noqa: E402
from trioman.toolkit.train.loop import photometric, render, train  # noqa: E402

SHIFT = np.array([0.06, -0.04, 0.0], np.float32)  # m, the root shift of the test frames' pixels, in camera axes


def world_shift(viewmat: np.ndarray, shift: np.ndarray) -> np.ndarray:
    """``shift`` (across the image: right, down) in the world frame of a camera with world->camera ``viewmat``."""
    return (viewmat[:3, :3].T @ shift).astype(np.float32)


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    """A 64 px plain subject whose test frames show an untrained tiny avatar of its body with the root moved by
    SHIFT across the image (premultiplied on black, its alpha the mask), their stored poses unmoved; the avatar."""
    return rendered_scene(tmp_path_factory.mktemp("refit"), SHIFT)


@pytest.fixture(scope="module")
def exact_scene(tmp_path_factory):
    """As ``scene``, the test frames rendered at their stored poses: each is at its best pose already."""
    return rendered_scene(tmp_path_factory.mktemp("refit_exact"), np.zeros(3, np.float32))


def rendered_scene(root, shift: np.ndarray):
    s = load_subject(synthesize_subject(SynthConfig(seed=3, size=64, frames=8, texture_size=256), root / "synth",
                                        progress=False).root)
    torch.manual_seed(0)
    model = GaussianAvatar(s.body, TINY_AVATAR)
    test = set(s.indices("test").tolist())
    images, masks = [], []
    with torch.no_grad():
        for i in range(len(s.poses)):
            if i not in test:
                images.append(s.image(i))
                masks.append(s.mask(i))
                continue
            g = model(torch.from_numpy(np.array(s.poses[i])), torch.from_numpy(s.trans[i] + world_shift(s.viewmat[i], shift))).refined
            out = rasterize(g.means, g.quats, g.scales, g.opacities, g.colors, torch.from_numpy(s.viewmat[i]),
                            torch.from_numpy(s.K[i]), s.width, s.height, background=torch.zeros(3))
            images.append(out.rgb.clamp(0, 1).numpy())
            masks.append(out.alpha.clamp(0, 1).numpy())
    shifted = save_subject(root / "s", body=s.body, poses=s.poses, trans=s.trans, K=s.K, viewmat=s.viewmat,
                           split=s.split, sequence=s.sequence, images=images, masks=masks, width=s.width,
                           height=s.height, body_model=s.body_model, background=(0.0, 0.0, 0.0),
                           phenotype=s.meta["phenotype"], generator={"tool": "test"})
    return shifted, model


def loss_at(model, subject, i, pose, trans) -> float:
    gt = subject.image(i) + (1 - subject.mask(i))[..., None]
    with torch.no_grad():
        g = model(torch.from_numpy(np.array(pose)), torch.from_numpy(np.array(trans))).refined
        img = render(g, torch.from_numpy(subject.viewmat[i]), torch.from_numpy(subject.K[i]), subject.width,
                     subject.height, torch.ones(3))
    return float(photometric(img, torch.from_numpy(gt), TrainConfig()))


def test_refit_finds_a_known_root_shift_and_leaves_the_avatar_and_other_frames_alone(scene):
    subject, model = scene
    before = {n: p.detach().clone() for n, p in model.named_parameters()}
    grads = {n: p.requires_grad for n, p in model.named_parameters()}
    cfg, seen = TrainConfig(), []
    poses, trans = refit_poses(model, subject, "test", subject.poses, subject.trans,
                               lambda img, gt: photometric(img, gt, cfg), render,
                               RefitSettings(steps=60), seen.append)
    test = subject.indices("test")
    assert seen == list(range(1, len(test) + 1)) and poses.dtype == np.float32
    train_ids = subject.indices("train")
    assert np.array_equal(poses[train_ids], subject.poses[train_ids]) and np.array_equal(trans[train_ids], subject.trans[train_ids])
    for i in test:
        found = subject.viewmat[i][:3, :3] @ (trans[i] - subject.trans[i])  # in camera axes
        # the root's rotation can take part of a shift across the image: most of it, the right way, is asked for
        along = float(found[:2] @ SHIFT[:2]) / float(SHIFT[:2] @ SHIFT[:2])
        across = abs(float(found[0] * SHIFT[1] - found[1] * SHIFT[0])) / float(SHIFT[:2] @ SHIFT[:2])
        assert along > 0.5 and across < 0.25, (i, found)
        assert loss_at(model, subject, i, poses[i], trans[i]) < 0.1 * loss_at(model, subject, i, subject.poses[i], subject.trans[i])
    for n, p in model.named_parameters():
        assert torch.equal(p, before[n]) and p.requires_grad == grads[n]


def test_a_frame_at_its_best_pose_stays_there(exact_scene):
    """At full size a frame rendered at its stored pose is at the loss's minimum (up to the penalty): the refit may
    not walk it away, nor raise its loss."""
    subject, model = exact_scene
    cfg = TrainConfig()
    poses, trans = refit_poses(model, subject, "test", subject.poses, subject.trans,
                               lambda img, gt: photometric(img, gt, cfg), render)
    for i in subject.indices("test"):
        assert np.abs(poses[i] - subject.poses[i]).max() < 0.01 and np.linalg.norm(trans[i] - subject.trans[i]) < 2e-3
        assert loss_at(model, subject, i, poses[i], trans[i]) <= loss_at(model, subject, i, subject.poses[i], subject.trans[i])


def test_the_search_against_a_quadratic_of_known_minimum():
    """Badly scaled (curvatures 1e-2 to 1e2): the line search finds the minimum; started at it, it stays."""
    c = torch.tensor([0.3, -0.2, 0.05, 0.0])
    w = torch.tensor([1e-2, 1.0, 1e2, 10.0])
    found = _minimise(lambda d: (w * (d - c).square()).sum() + 1.0, 4, 50)
    assert torch.allclose(found, c, atol=1e-3)
    assert torch.equal(_minimise(lambda d: (w * d.square()).sum(), 4, 50), torch.zeros(4))
    assert torch.equal(_minimise(lambda d: d.sum() * float("inf"), 4, 5), torch.zeros(4))


def test_a_frame_whose_loss_turns_non_finite_keeps_its_pose(scene):
    subject, model = scene
    poses, trans = refit_poses(model, subject, "test", subject.poses, subject.trans,
                               lambda img, gt: img.sum() * float("nan"), render, RefitSettings(steps=3))
    assert np.array_equal(poses, subject.poses) and np.array_equal(trans, subject.trans)


@pytest.mark.parametrize("field, value", [("steps", 0), ("steps", 2.5), ("steps", True), ("penalty", -1.0),
                                          ("penalty", float("nan")), ("scale", 0.0), ("scale", 2.0)])
def test_bad_refit_settings_are_named(field, value):
    with pytest.raises(ValueError, match=f"^{field}: "):
        RefitSettings(**{field: value})


def test_evaluation_at_refitted_poses_and_its_command(scene, tmp_path, capsys):
    subject, _ = scene
    run = train(subject.root, tmp_path / "r", TrainConfig(iterations=2, checkpoint_every=2, avatar=TINY_AVATAR),
                progress=False)
    stored = evaluate(run, "test", tmp_path / "e_stored", progress=False, video=False, poses="stored")
    refit = evaluate(run, "test", tmp_path / "e_opt", progress=False, video=False, poses="optimised",
                     refit=RefitSettings(steps=2))
    assert refit["poses"] == "stored, refitted to each frame (L-BFGS, at most 2 steps, at full size)"
    assert (refit["poses_key"], stored["poses_key"]) == ("optimised (L-BFGS, at most 2 steps, penalty 1, scale 1)", "stored")
    assert refit["frames"] == stored["frames"] and refit["mean"]["psnr"] != stored["mean"]["psnr"]
    from trioman.cli import main

    assert main(["eval", str(run), "--poses", "optimised", "--no-video", "--quiet", "--out", str(tmp_path / "c")]) == 0
    assert "PSNR" in capsys.readouterr().out
    assert json.loads((tmp_path / "c" / "summary.json").read_text())["poses"].startswith("stored, refitted to each frame")
