"""The motion file format: round trip, every validation error, subject import and --motion specs."""

from __future__ import annotations

import numpy as np
import pytest

from tests.runtime.factories import JOINTS, NAMES, PARENTS, make_fields, make_images
from trioman.runtime import motions
from trioman.runtime.formats import FormatError, load_motion, save_motion, save_subject
from trioman.runtime.formats.motion import motion_from_spec, motion_from_subject
from trioman.runtime.skeleton import Skeleton


@pytest.fixture
def skeleton():
    return Skeleton(tuple(NAMES), np.array(PARENTS), JOINTS)


@pytest.fixture
def motion_file(tmp_path, skeleton):
    return save_motion(tmp_path / "wave.npz", motions.wave(skeleton, 8))


def test_round_trip(motion_file, skeleton):
    m = load_motion(motion_file)
    ref = motions.wave(skeleton, 8)
    assert m.name == ref.name and m.joint_names == tuple(NAMES) and m.fps == ref.fps
    np.testing.assert_allclose(m.pose, ref.pose, atol=1e-6)
    np.testing.assert_allclose(m.trans, ref.trans, atol=1e-6)
    assert [p.name for p in motion_file.parent.iterdir()] == ["wave.npz"]  # no temporary left behind


def _rewrite(path, **changes):
    arrays = dict(np.load(path, allow_pickle=False))
    arrays.update(changes)
    for k in [k for k, v in changes.items() if v is None]:
        del arrays[k]
    with open(path, "wb") as f:
        np.savez(f, **arrays)


@pytest.mark.parametrize("changes, match", [
    (dict(poses=None), "poses: missing array"),
    (dict(format=np.array("something-else")), "format: expected 'trioman-motion'"),
    (dict(version=np.array(9)), "version: unknown version 9"),
    (dict(fps=np.array(0.0)), r"fps: must lie in \[0.1, 1000.0\] frames per second, got 0.0"),
    (dict(fps=np.array(1e-30)), r"fps: must lie in \[0.1, 1000.0\] frames per second, got 1e-30"),  # issue 41, U3
    (dict(fps=np.array([30.0])), "fps: expected a scalar"),
    (dict(joint_names=np.array(["a", "a"])), "joint_names: "),
    (dict(poses=np.zeros((8, 3, 3), np.float32)), r"poses: expected float \[T in \[1, 108000\], 18, 3\]"),
    (dict(trans=np.zeros((7, 3), np.float32)), r"trans: expected float \[8, 3\]"),
    (dict(poses=np.full((8, 18, 3), np.nan, np.float32)), "poses: 432 value"),
    # issue 18, case 8: a 1e30 rad rotation reported NaN means without naming the motion file
    (dict(poses=np.pad(np.full((1, 1, 3), 1e30, np.float32), ((3, 4), (2, 15), (0, 0)))),
     r"poses: frame 3, joint '[\w.]+': a rotation angle of 1\.73e\+30 \(rad\), beyond 1000"),
    (dict(trans=np.full((8, 3), 1e30, np.float32)), r"trans: frame 0: a translation of 1e\+30 \(m\), beyond 10000"),
])
def test_every_validation_error_names_file_and_field(motion_file, changes, match):
    _rewrite(motion_file, **changes)
    with pytest.raises(FormatError, match=match) as err:
        load_motion(motion_file)
    assert str(motion_file) in str(err.value)


def test_truncated_and_pickled_files_are_refused(motion_file, tmp_path):
    data = motion_file.read_bytes()
    motion_file.write_bytes(data[: len(data) // 2])
    with pytest.raises(FormatError, match="not a valid .npz"):
        load_motion(motion_file)
    bad = tmp_path / "obj.npz"
    np.savez(bad, format=np.array(["x", None], dtype=object))
    with pytest.raises(FormatError, match="pickle"):
        load_motion(bad)


def test_subject_test_poses_import(tmp_path):
    fields = make_fields()
    images, masks = make_images()
    path = save_subject(tmp_path / "subj", images=images, masks=masks, **fields).root
    m = motion_from_subject(path)
    assert m.num_frames == 2 and m.joint_names == ("root", "mid", "tip")
    np.testing.assert_allclose(m.pose, fields["poses"][-2:])
    assert motion_from_subject(path, "train", "walk").num_frames == 3
    with pytest.raises(FormatError, match="sequence: no sequence 'jog'"):
        motion_from_subject(path, "test", "jog")
    sk = fields["body"].skeleton
    assert motion_from_spec(f"{path}:dance", sk).num_frames == 2
    assert motion_from_spec(str(path), sk).num_frames == 2


def test_specs(motion_file, skeleton):
    assert motion_from_spec("jump", skeleton, 12).num_frames == 12
    assert motion_from_spec("walk", skeleton).num_frames == motions.DEFAULT_FRAMES["walk"]
    assert motion_from_spec(str(motion_file), skeleton).num_frames == 8
    with pytest.raises(FileNotFoundError, match="neither a shipped motion"):
        motion_from_spec("moonwalk", skeleton)


def test_a_motion_that_decompresses_into_gigabytes_is_not_read(tmp_path, monkeypatch):
    """Issue 41, D10: a 235 KB file declaring 10^7 frames made `render --pose M.npz@5` take 4 GB. The limit is
    checked on the zip entries' sizes before any array is read (here made small to keep the test light)."""
    from trioman.runtime.formats import FormatError
    from trioman.runtime.formats import motion as motion_format

    monkeypatch.setattr(motion_format, "MAX_ARRAY_BYTES", 100_000)
    path = tmp_path / "huge.npz"
    T = 100_000 // (18 * 3 * 4) + 1
    np.savez_compressed(path, format=np.array("trioman-motion"), version=np.array(1), name=np.array("huge"),
                        fps=np.array(30.0), joint_names=np.array([f"j{i}" for i in range(18)]),
                        poses=np.zeros((T, 18, 3), np.float32), trans=np.zeros((T, 3), np.float32))
    assert path.stat().st_size < 5_000
    with pytest.raises(FormatError, match=r"poses: \d+ bytes once decompressed, more than the 100000 this file can need"):
        motion_format.load_motion(path)
