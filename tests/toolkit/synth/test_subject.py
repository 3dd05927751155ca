"""Synthetic subjects end to end at a tiny size: format, framing, determinism, pose noise."""

import hashlib
from pathlib import Path

import cv2
import numpy as np
import pytest

pytest.importorskip("torch")
pytest.importorskip("anny")

from trioman.runtime.formats import load_subject  # noqa: E402
from trioman.toolkit.synth.subject import SynthConfig, phenotype_from_seed, synthesize_subject  # noqa: E402

TINY = dict(size=48, frames=12, texture_size=256)


def digest(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): hashlib.sha1(p.read_bytes()).hexdigest() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def subject_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("synth") / "s0"
    synthesize_subject(SynthConfig(seed=3, **TINY), out, progress=False)
    return out


def test_subject_loads_and_has_both_splits(subject_dir):
    s = load_subject(subject_dir)
    assert s.num_frames == 12 and s.width == s.height == 48
    assert len(s.indices("train")) == 8 and len(s.indices("test")) == 4
    assert set(s.sequences) == {"train_turn", "test_arms_raised", "test_squat", "test_step", "test_wave"}
    assert s.body_model == "anny" and s.meta["phenotype"] == phenotype_from_seed(3)
    np.testing.assert_array_equal(s.poses, s.poses_true)  # no pose noise asked
    assert (subject_dir / "contact_sheet.png").stat().st_size > 1000


def test_every_frame_is_framed_and_textured(subject_dir):
    s = load_subject(subject_dir)
    for i in range(s.num_frames):
        mask, img = s.mask(i), s.image(i)
        assert mask.sum() > 0.05 * mask.size, f"frame {i}: subject too small or missing"
        border = np.concatenate([mask[0], mask[-1], mask[:, 0], mask[:, -1]])
        assert border.max() == 0, f"frame {i}: subject touches the image border"
        inside = img[mask > 0.99]
        assert inside.std() > 0.05, f"frame {i}: no texture detail"
        assert img[mask == 0].max() == 0, f"frame {i}: background must be black"


def test_mask_agrees_with_projected_posed_mesh(subject_dir):
    """The stored pose, camera and body reproduce the rendered silhouette (the format is self-consistent)."""
    from trioman.runtime.cameras import project

    s = load_subject(subject_dir)
    for i in (0, 9):
        uv, z = project(s.posed_vertices(i, true_pose=True), s.viewmat[i].astype(np.float64), s.K[i].astype(np.float64))
        assert np.all(z > 0)
        j, k = np.clip(uv.astype(int), 0, 47).T
        # Every vertex lands on the silhouette, up to one pixel for sub-pixel fingers.
        near_subject = cv2.dilate(s.mask(i), np.ones((3, 3), np.uint8)) > 0
        assert near_subject[k, j].mean() > 0.995
        # And the silhouette is covered by the mesh: no rendered pixel far from every vertex.
        hit = np.zeros_like(near_subject)
        hit[k, j] = True
        assert (s.mask(i) > 0.5)[~cv2.dilate(hit.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)].sum() == 0


def test_same_seed_same_bytes(tmp_path, subject_dir):
    synthesize_subject(SynthConfig(seed=3, **TINY), tmp_path / "again", progress=False)
    assert digest(tmp_path / "again") == digest(subject_dir)


def test_pose_noise_perturbs_stored_poses_only(tmp_path, subject_dir):
    out = tmp_path / "noisy"
    synthesize_subject(SynthConfig(seed=3, pose_noise_deg=3.0, **TINY), out, progress=False)
    noisy, clean = load_subject(out), load_subject(subject_dir)
    np.testing.assert_array_equal(noisy.poses_true, clean.poses_true)
    dev = np.rad2deg(np.abs(noisy.poses - noisy.poses_true))
    assert 1.0 < dev.mean() < 6.0
    assert (out / "images" / "000005.png").read_bytes() == (subject_dir / "images" / "000005.png").read_bytes()


def test_refuses_to_overwrite(subject_dir):
    with pytest.raises(FileExistsError):
        synthesize_subject(SynthConfig(seed=3, **TINY), subject_dir, progress=False)


@pytest.mark.parametrize(
    "kwargs, field",
    [({"size": 8}, "size"), ({"frames": 3}, "frames"), ({"pose_noise_deg": -1.0}, "pose_noise_deg"), ({"test_fraction": 1.0}, "test_fraction"),
     ({"coverage": 0.0}, "coverage"), ({"coverage": 1.5}, "coverage")],
)
def test_bad_config_is_named(kwargs, field):
    with pytest.raises(ValueError, match=field):
        SynthConfig(**kwargs)


def test_yaw_turns_the_posed_body_rigidly():
    """Turning a motion about z moves every posed vertex by that rotation (pose and translation agree)."""
    from trioman.runtime import motions
    from trioman.runtime.rotations import axis_angle_to_matrix
    from trioman.toolkit.synth.subject import _yawed, build_body

    mesh, _ = build_body(SynthConfig(seed=1, **TINY))
    m = motions.squat(mesh.skeleton, 3)
    turned = _yawed(m, 1.1, mesh.skeleton.joints[0])
    Rz = axis_angle_to_matrix(np.array([0.0, 0.0, 1.1]))
    np.testing.assert_allclose(mesh.pose(turned.pose[2], turned.trans[2]), mesh.pose(m.pose[2], m.trans[2]) @ Rz.T, atol=1e-9)


def test_coverage_limits_the_training_turn():
    """coverage c: the training frames' root turns through c of a full turn about z, the test frames are unchanged."""
    from trioman.toolkit.synth.subject import plan_sequences

    from trioman.toolkit.synth.subject import build_body

    mesh, _ = build_body(SynthConfig(seed=1, **TINY))
    full, third = (plan_sequences(mesh, SynthConfig(seed=1, coverage=c, **TINY)) for c in (1.0, 1 / 3))
    train = [i for i, s in enumerate(full.split) if s == "train"]
    test = [i for i, s in enumerate(full.split) if s == "test"]
    yaw = third.pose[train, 0, 2]
    assert yaw.min() >= -1e-9 and yaw.max() <= 2 * np.pi / 3 + 1e-9 and yaw.max() > 0.5 * 2 * np.pi / 3
    assert full.pose[train, 0, 2].max() > 1.5 * np.pi  # all round (the last frame is one step short of 2 pi)
    np.testing.assert_array_equal(full.pose[test], third.pose[test])

