"""One image of an avatar (runtime/still.py): the pose and camera specs, and their errors naming the parameter."""

from __future__ import annotations

import numpy as np
import pytest

from trioman.runtime.animate import RenderOptions
from trioman.runtime.formats import load_avatar
from trioman.runtime.formats.motion import save_motion
from trioman.runtime.motions import Motion
from trioman.runtime.still import render_still, resolve_pose, split_frame


@pytest.fixture
def motion(avatar_dir, tmp_path):
    """A 4-frame motion of the avatar's own joints: its first joint turning."""
    names = load_avatar(avatar_dir).skeleton.joint_names
    pose = np.zeros((4, len(names), 3))
    pose[:, 0, 2] = np.linspace(0, 1.5, 4)
    return save_motion(tmp_path / "m.npz", Motion("m", pose, np.zeros((4, 3)), tuple(names)))


def test_a_still_at_rest_from_the_front_and_an_angle(avatar_dir, motion):
    avatar = load_avatar(avatar_dir)
    front = render_still(avatar, "rest", RenderOptions(size=32))
    side = render_still(avatar, "rest", RenderOptions(size=32, camera="90,0"))
    assert front.rgb.shape == (32, 32, 3) and (front.width, front.height) == (32, 32)
    assert np.isfinite(front.rgb).all() and not np.allclose(front.rgb, side.rgb)
    pose, trans, cam = resolve_pose(f"{motion}@3", avatar.skeleton)
    assert pose[0, 2] == pytest.approx(1.5) and trans.shape == (3,) and cam is None
    assert not np.allclose(render_still(avatar, f"{motion}@3", RenderOptions(size=32)).rgb, front.rgb)


@pytest.mark.parametrize("pose, cfg, message", [
    ("walk@x", RenderOptions(), r"^pose: frame after '@' must be an integer, got 'x'"),
    ("{motion}@100000", RenderOptions(), r"^pose: frame 100000 is out of range for '.*m.npz' \(4 frames\)"),
    ("rest", RenderOptions(camera="subject"), r"^camera: 'subject' needs `pose` SUBJECT@FRAME"),
    ("rest", RenderOptions(camera="left"), r"^camera: expected front, subject or AZ,EL in degrees, got 'left'"),
    ("rest", RenderOptions(camera="nan,0"), r"^camera: AZ,EL must be finite degrees"),
])
def test_bad_specs_name_their_parameter(avatar_dir, motion, pose, cfg, message):
    with pytest.raises(ValueError, match=message):
        render_still(load_avatar(avatar_dir), pose.format(motion=motion), cfg)


def test_split_frame():
    assert split_frame("walk") == ("walk", 0) and split_frame("a@b@7") == ("a@b", 7)
