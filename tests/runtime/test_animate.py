"""``trioman animate``: framing that survives outliers, empty clips refused, MP4 sides (issue 18, cases 7 and 9)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from tests.runtime.factories import edit_npz, transparent
from trioman.cli import main
from trioman.runtime.animate import animate
from trioman.runtime.formats import load_avatar
from trioman.runtime.motions import Motion


def still(avatar, frames=3, trans=(0.0, 0.0, 0.0)) -> Motion:
    J = avatar.skeleton.num_joints
    return Motion("still", np.zeros((frames, J, 3), np.float32), np.tile(np.float32(trans), (frames, 1)),
                  avatar.skeleton.joint_names, 10.0)


def coverage(video) -> float:
    """Share of the first frame's pixels that are not the white background."""
    cap = cv2.VideoCapture(str(video))
    ok, frame = cap.read()
    cap.release()
    assert ok
    return float((frame.min(-1) < 200).mean())


def test_one_far_gaussian_does_not_shrink_the_avatar(avatar_dir, tmp_path):
    normal = animate(load_avatar(avatar_dir), still(load_avatar(avatar_dir)), tmp_path / "a.mp4", size=64, progress=False)
    with np.load(avatar_dir / "gaussians.npz") as z:
        positions = z["positions"].copy()
    positions[0] = [100.0, 0.0, 0.0]  # one outlier Gaussian at 100 m
    edit_npz(avatar_dir, "gaussians.npz", positions=positions)
    outlier = animate(load_avatar(avatar_dir), still(load_avatar(avatar_dir)), tmp_path / "b.mp4", size=64, progress=False)
    assert normal["empty"] == outlier["empty"] == []
    assert coverage(tmp_path / "b.mp4") > 0.5 * coverage(tmp_path / "a.mp4") > 0


def test_a_clip_that_shows_nothing_is_refused_and_leaves_nothing(avatar_dir, tmp_path):
    avatar = load_avatar(avatar_dir)
    frames = tmp_path / "frames"
    with pytest.raises(ValueError, match=r"^motion still: all 3 frames show nothing of the avatar"):
        animate(transparent(avatar_dir), still(avatar), tmp_path / "v.mp4", size=32, frames_dir=frames, progress=False)
    assert not (tmp_path / "v.mp4").exists() and list(frames.iterdir()) == []
    with pytest.raises(ValueError, match=r"^motion still: the avatar cannot be framed: points: 1e\+30 m from the origin"):
        animate(avatar, still(avatar, trans=(1e30, 0, 0)), tmp_path / "v.mp4", size=32, progress=False)


@pytest.mark.parametrize("args, message", [
    (["--size", "257"], "--size: 257 is odd, and an MP4 needs even sides (it would be 256x256); use 256 or 258"),
    (["--azimuth", "nan"], "--azimuth: must be a finite number of degrees, got nan"),
    (["--frames", "100000000"], "--frames: must lie in [1, 108000] (an hour at 30 fps), got 100000000"),  # issue 41, D13
])
def test_command_line_refusals(avatar_dir, tmp_path, capsys, args, message):
    assert main(["animate", str(avatar_dir), "--motion", "walk", "--out", str(tmp_path / "v.mp4"), *args]) == 1
    assert message in capsys.readouterr().err
    assert not (tmp_path / "v.mp4").exists()


def test_the_mp4_has_the_requested_even_size(avatar_dir, tmp_path):
    avatar = load_avatar(avatar_dir)
    animate(avatar, still(avatar), tmp_path / "v.mp4", size=34, progress=False)
    cap = cv2.VideoCapture(str(tmp_path / "v.mp4"))
    assert (cap.get(cv2.CAP_PROP_FRAME_WIDTH), cap.get(cv2.CAP_PROP_FRAME_HEIGHT)) == (34, 34)
    cap.release()


def test_nothing_is_written_over_or_into_an_input(avatar_dir, tmp_path, capsys):
    # issue 41, D7: `animate --motion SUBJECT --frames-dir SUBJECT` wrote PNGs into the subject
    motion = tmp_path / "motion"
    motion.mkdir()  # stands for a subject folder given as --motion
    before = sorted(p.name for p in avatar_dir.iterdir())
    cases = [(["--frames-dir", str(motion)], f"--frames-dir: {motion}: is the input {motion}"),
             (["--frames-dir", str(avatar_dir / "frames")], "--frames-dir: " + str(avatar_dir / "frames") + ": lies inside"),
             (["--out", str(avatar_dir / "v.mp4")], "--out: " + str(avatar_dir / "v.mp4") + ": lies inside")]
    for args, message in cases:
        argv = ["animate", str(avatar_dir), "--motion", str(motion), "--out", str(tmp_path / "v.mp4"), "--size", "32"]
        assert main(argv + args) == 1
        assert message in capsys.readouterr().err
    assert sorted(p.name for p in avatar_dir.iterdir()) == before and list(motion.iterdir()) == []
    assert not (tmp_path / "v.mp4").exists()
