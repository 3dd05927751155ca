"""Every layout the fixtures write (tests/toolkit/importers/layouts.py, from the upstream writers' code) -> import ->
train a few iterations at a tiny size -> eval -> export avatar -> animate with ``--camera orbit``, upright.

Upright: the animation's own cameras (recorded as ``animate`` hands them to the renderer) see the posed head above
the posed feet in every frame, and the feet stand below the head along the world's +z. A person imported upside
down (issue 25, item 2) fails both."""

from __future__ import annotations

import json

import numpy as np
import pytest

pytest.importorskip("torch")
pytest.importorskip("anny")
pytest.importorskip("smplx", reason="needs the 'smplx' extra: pip install 'trioman[smplx]'")

from trioman.cli import main  # noqa: E402
from trioman.runtime import render as runtime_render  # noqa: E402
from trioman.runtime.formats import load_avatar  # noqa: E402
from trioman.runtime.formats.motion import load_motion, motion_from_subject, save_motion  # noqa: E402
from trioman.toolkit.avatar.model import AvatarConfig  # noqa: E402
from trioman.toolkit.train.config import preset  # noqa: E402
from trioman.toolkit.train.loop import train  # noqa: E402
from tests.toolkit.importers import layouts  # noqa: E402

# One tiny training config for every layout: a few hundred Gaussians on the unsubdivided SMPL-X mesh, a small
# triplane and MLPs, two steps. What is tested is the data path (import -> train -> export -> animate), not quality.
TINY = preset("quick", iterations=2, checkpoint_every=2, avatar=AvatarConfig(
    subdivisions=0, keep=0.05, point_colors=True, scale_init=1.0, pose_dependent=False, triplane_res=8,
    triplane_channels=4, hidden=8))
SIZE = 64  # the animation's side, pixels


def _xhumans(root, model_dir):
    layouts.write_xhumans(root, model_dir)
    return ["exavatar", str(root), "--dataset", "xhumans", "--subject", "00028", "--allow-pickle"]


def _xhumans_exavatar_fits(root, model_dir):  # ExAvatar's per-take fits: no pickle is read, so no --allow-pickle
    layouts.write_xhumans(root, model_dir, exavatar_takes=("Take1", "Take2", "Take9"))
    return ["exavatar", str(root), "--dataset", "xhumans", "--subject", "00028"]


def _neuman(root, model_dir):
    layouts.write_neuman(root, model_dir)
    return ["exavatar", str(root / "bike"), "--dataset", "neuman"]


def _custom_virtual(root, model_dir):
    layouts.write_custom(root, model_dir)
    return ["exavatar", str(root / "myvideo"), "--dataset", "custom"]


def _custom_colmap(root, model_dir):
    layouts.write_custom(root, model_dir, colmap=True)
    return ["exavatar", str(root / "myvideo"), "--dataset", "custom"]


def _smplerx(root, model_dir):
    layouts.write_smplerx(root, model_dir)
    return ["smplx-fits", str(root / "frames"), str(root / "fits")]


LAYOUTS = {"xhumans": _xhumans, "xhumans_exavatar_fits": _xhumans_exavatar_fits, "neuman": _neuman,
           "custom_virtual": _custom_virtual, "custom_colmap": _custom_colmap, "smplerx": _smplerx}


def record_cameras(monkeypatch) -> list[dict]:
    """Record what ``animate`` hands the renderer for each frame: the camera (viewmat, K) and the coverage."""
    calls: list[dict] = []
    real = runtime_render.rasterize

    def spy(*args, **kwargs):
        out = real(*args, **kwargs)
        calls.append({"viewmat": np.asarray(args[-4]), "K": np.asarray(args[-3]), "alpha": out.alpha})
        return out

    monkeypatch.setattr(runtime_render, "rasterize", spy)
    return calls


def check_upright(avatar, motion, calls) -> None:
    """In every frame of the orbit the posed head is above the posed feet along +z and in the image (v grows
    downwards, OpenCV), by a good part of the image, and both project onto the rendered avatar's extent."""
    names = avatar.skeleton.joint_names
    head, feet = names.index("head"), [names.index("left_foot"), names.index("right_foot")]
    assert len(calls) == motion.num_frames >= 3
    eyes = []
    for i, call in enumerate(calls):
        joints = avatar.skeleton.forward_kinematics(motion.pose[i], motion.trans[i])[:, :3, 3]
        z = joints[:, 2]
        assert z[head] > z[feet].max() + 0.5, f"frame {i}: head at z {z[head]:.2f} m, feet at {z[feet]} m"
        cam = joints[[head] + feet] @ call["viewmat"][:3, :3].T + call["viewmat"][:3, 3]
        assert np.all(cam[:, 2] > 0), f"frame {i}: head or feet behind the orbit camera"
        uv = cam[:, :2] / cam[:, 2:] * np.diag(call["K"])[:2] + call["K"][:2, 2]
        assert uv[0, 1] < uv[1:, 1].min() - 0.25 * SIZE, f"frame {i}: head at v {uv[0, 1]:.1f} px, feet at {uv[1:, 1]}"
        rows, cols = np.nonzero(call["alpha"] > 0.05)
        assert len(rows), f"frame {i}: nothing of the avatar rendered"
        lo, hi = np.array([cols.min(), rows.min()]) - 3, np.array([cols.max(), rows.max()]) + 4
        assert np.all((uv >= lo) & (uv <= hi)), f"frame {i}: head/feet at {uv.round(1).tolist()} px, avatar in {lo}-{hi}"
        eyes.append(np.linalg.inv(call["viewmat"])[:3, 3])
    eyes = np.array(eyes)
    assert np.ptp(eyes[:, :2], axis=0).max() > 0.5, "the camera did not orbit"


@pytest.mark.parametrize("layout", list(LAYOUTS))
def test_import_train_export_animate_upright(tmp_path, smplx_model_dir, capsys, monkeypatch, layout):
    subject, run, avatar = tmp_path / "subject", tmp_path / "run", tmp_path / "avatar"
    source = LAYOUTS[layout](tmp_path / "data", smplx_model_dir)
    argv = ["import", *source, "--out", str(subject), "--body-model-dir", str(smplx_model_dir)]
    assert main(argv) == 0, f"trioman import: {capsys.readouterr().err}"
    train(subject, run, TINY, progress=False)
    motion = tmp_path / "train_poses.npz"  # the subject's training poses: several frames, so the camera orbits
    save_motion(motion, motion_from_subject(subject, "train"))
    steps = [
        ["eval", str(run), "--quiet", "--no-video", "--protocol", "exavatar"],
        ["export", "avatar", str(run), "--out", str(avatar)],
        ["animate", str(avatar), "--motion", str(motion), "--out", str(tmp_path / "orbit.mp4"), "--size", str(SIZE),
         "--camera", "orbit", "--quiet"],
    ]
    calls = []
    for argv in steps:
        if argv[0] == "animate":
            calls = record_cameras(monkeypatch)
        assert main(argv) == 0, f"trioman {' '.join(argv[:2])}: {capsys.readouterr().err}"
    summary = json.loads((run / "eval_test" / "summary.json").read_text())
    assert summary["frames"] >= 1
    e = summary["exavatar"]  # ExAvatar's protocol beside ours: the same masked composite, both SSIM borders
    assert e["psnr"] == summary["mean"]["psnr"] and e["ssim"] == summary["mean"]["ssim"] and 0 < e["ssim_tm14"] <= 1
    loaded = load_avatar(avatar)
    assert loaded.meta["body_model"] == "smplx" and loaded.skeleton.num_joints == 55
    assert (tmp_path / "orbit.mp4").stat().st_size > 0
    check_upright(loaded, load_motion(motion).for_skeleton(loaded.skeleton), calls)
