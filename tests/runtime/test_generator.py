"""Generator sampling: joint groups, determinism, clamps, statistics, camera orbit."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tests.runtime.factories import JOINTS, NAMES, PARENTS
from trioman.runtime import generator as gen
from trioman.runtime.cameras import camera_center, orbit_viewmat
from trioman.runtime.skeleton import Skeleton

# The 104 bones of the Anny body the toolkit uses (anny 0.6.2, default rig), in Anny's order.
ANNY_NAMES = (
    "root", "pelvis.L", "upperleg01.L", "upperleg02.L", "lowerleg01.L", "lowerleg02.L", "foot.L", "toe1-1.L",
    "toe1-2.L", "toe2-1.L", "toe2-2.L", "toe2-3.L", "toe3-1.L", "toe3-2.L", "toe3-3.L", "toe4-1.L",
    "toe4-2.L", "toe4-3.L", "toe5-1.L", "toe5-2.L", "toe5-3.L", "pelvis.R", "upperleg01.R", "upperleg02.R",
    "lowerleg01.R", "lowerleg02.R", "foot.R", "toe1-1.R", "toe1-2.R", "toe2-1.R", "toe2-2.R", "toe2-3.R",
    "toe3-1.R", "toe3-2.R", "toe3-3.R", "toe4-1.R", "toe4-2.R", "toe4-3.R", "toe5-1.R", "toe5-2.R",
    "toe5-3.R", "spine05", "spine04", "spine03", "spine02", "spine01", "clavicle.L", "shoulder01.L",
    "upperarm01.L", "upperarm02.L", "lowerarm01.L", "lowerarm02.L", "wrist.L", "finger1-1.L", "finger1-2.L",
    "finger1-3.L", "metacarpal1.L", "finger2-1.L", "finger2-2.L", "finger2-3.L", "metacarpal2.L",
    "finger3-1.L", "finger3-2.L", "finger3-3.L", "metacarpal3.L", "finger4-1.L", "finger4-2.L", "finger4-3.L",
    "metacarpal4.L", "finger5-1.L", "finger5-2.L", "finger5-3.L", "clavicle.R", "shoulder01.R",
    "upperarm01.R", "upperarm02.R", "lowerarm01.R", "lowerarm02.R", "wrist.R", "finger1-1.R", "finger1-2.R",
    "finger1-3.R", "metacarpal1.R", "finger2-1.R", "finger2-2.R", "finger2-3.R", "metacarpal2.R",
    "finger3-1.R", "finger3-2.R", "finger3-3.R", "metacarpal3.R", "finger4-1.R", "finger4-2.R", "finger4-3.R",
    "metacarpal4.R", "finger5-1.R", "finger5-2.R", "finger5-3.R", "neck01", "neck02", "neck03", "head",
    "eye.L", "eye.R",
)
# Test oracle: the expected group of a non-root Anny joint by name prefix.
PREFIXES = {
    "torso": ("pelvis", "spine", "neck"),
    "legs": ("upperleg", "lowerleg", "foot", "toe"),
    "arms": ("clavicle", "shoulder", "upperarm", "lowerarm"),
    "hands": ("wrist", "finger", "metacarpal"),
    "head": ("head", "eye"),
}
ZERO = {g: 0.0 for g in gen.GROUPS}
HUGE = {g: 1e6 for g in gen.GROUPS}


@pytest.fixture
def skeleton():
    return Skeleton(tuple(NAMES), np.array(PARENTS), JOINTS)


@pytest.fixture
def frame(skeleton):
    rng = np.random.default_rng(0)
    pose = rng.normal(scale=0.3, size=(skeleton.num_joints, 3))
    trans = np.array([0.2, -0.1, 0.9])
    center = gen.subject_center(skeleton, pose, trans)
    return pose, trans, orbit_viewmat(center, 0.3, 0.2, 3.0)


def _elevation_distance(viewmat, center):
    o = camera_center(viewmat) - center
    return math.atan2(o[2], math.hypot(o[0], o[1])), float(np.linalg.norm(o))


def _expected_group(name):
    hits = [g for g, prefixes in PREFIXES.items() if name.startswith(prefixes)]
    assert len(hits) == 1, (name, hits)
    return hits[0]


def _check_groups(names):
    sk = Skeleton(tuple(names), np.arange(-1, len(names) - 1), np.zeros((len(names), 3)))
    groups = gen.joint_groups(sk)
    assert len(groups) == len(names) and groups[0] == "root"
    assert list(groups[1:]) == [_expected_group(n) for n in names[1:]]


def test_every_anny_joint_in_exactly_one_group():
    assert len(ANNY_NAMES) == 104
    _check_groups(ANNY_NAMES)


def test_real_anny_joints_in_exactly_one_group(anny_body):  # skips without torch / anny
    _check_groups(anny_body.joint_names)


@pytest.mark.parametrize("name, group", [
    ("left_hip", "legs"), ("right_knee", "legs"), ("left_ankle", "legs"), ("left_collar", "arms"),
    ("right_elbow", "arms"), ("left_shoulder", "arms"), ("left_wrist", "hands"), ("left_index1", "hands"),
    ("right_thumb3", "hands"), ("jaw", "head"), ("left_eye_smplhf", "head"), ("spine3", "torso"),
    ("neck", "torso"), ("oris01", "head"), ("tail01", "other"), ("", "other"),
])
def test_smplx_and_unknown_names(name, group):
    assert gen.joint_group(name) == group


def test_same_seed_same_bytes_different_seed_differs(skeleton, frame):
    pose, trans, viewmat = frame
    a, b = (gen.sample(skeleton, pose, trans, viewmat, seed=7, n=3) for _ in range(2))
    c = gen.sample(skeleton, pose, trans, viewmat, seed=np.random.default_rng(7), n=3)
    for x, y, z in zip(a, b, c):
        for field in ("pose", "trans", "viewmat", "delta_pose", "center"):
            assert getattr(x, field).tobytes() == getattr(y, field).tobytes() == getattr(z, field).tobytes()
        assert x.camera == y.camera == z.camera
    d = gen.sample(skeleton, pose, trans, viewmat, seed=8, n=3)
    assert not np.array_equal(a[0].pose, d[0].pose) and a[0].camera != d[0].camera
    assert not np.array_equal(a[0].pose, a[1].pose), "candidates of one call differ"


def test_zero_sigma_is_identity(skeleton, frame):
    pose, trans, viewmat = frame
    cfg = gen.GeneratorConfig(pose_sigma=ZERO, azimuth_sigma=0, elevation_sigma=0, distance_sigma=0)
    for cand in gen.sample(skeleton, pose, trans, viewmat, seed=1, n=2, cfg=cfg):
        assert cand.pose.tobytes() == pose.tobytes() and cand.trans.tobytes() == trans.tobytes()
        assert not cand.delta_pose.any()
        assert cand.camera == gen.CameraDelta(0.0, 0.0, 0.0)
        np.testing.assert_allclose(cand.viewmat, viewmat, atol=1e-12)


def test_pose_clamps_hold_for_extreme_inputs_and_huge_sigmas(skeleton):
    rng = np.random.default_rng(3)
    J = skeleton.num_joints
    axes = rng.normal(size=(J, 3))
    near_pi = axes / np.linalg.norm(axes, axis=1, keepdims=True) * (np.pi - 1e-6)
    cfg = gen.GeneratorConfig(pose_sigma=HUGE)
    limit = np.array([cfg.max_angle[g] for g in gen.joint_groups(skeleton)])
    for pose in (near_pi, np.zeros((J, 3)), 50.0 * axes):
        for _ in range(20):
            new, trans = gen.perturb_pose(skeleton, pose, np.zeros(3), rng, cfg)
            assert np.isfinite(new).all() and not trans.any()
            angle = np.linalg.norm(new, axis=1)
            assert np.all(angle <= np.maximum(limit, np.linalg.norm(pose, axis=1)) + 1e-9)
            assert np.all(np.linalg.norm(new, axis=1) > 0.5 * np.minimum(limit, 1.0)), "huge sigma saturates"
    new, _ = gen.perturb_pose(skeleton, np.zeros((J, 3)), np.zeros(3), rng, cfg)
    assert np.all(np.linalg.norm(new, axis=1) <= limit + 1e-12)


def test_pose_statistics_match_sigmas(skeleton):
    rng = np.random.default_rng(5)
    cfg = gen.GeneratorConfig()
    zero = np.zeros((skeleton.num_joints, 3))
    deltas = np.stack([gen.perturb_pose(skeleton, zero, np.zeros(3), rng, cfg)[0] for _ in range(1500)])
    groups = np.array(gen.joint_groups(skeleton))
    assert set(groups) == {"root", "torso", "arms", "legs", "head"}
    for g in set(groups):
        d = deltas[:, groups == g]
        assert abs(d.mean()) < 0.02
        assert d.std() == pytest.approx(cfg.pose_sigma[g], rel=0.06, abs=1e-12), g


def test_camera_statistics_and_recorded_deltas(skeleton, frame):
    pose, trans, viewmat = frame
    cfg = gen.GeneratorConfig(pose_sigma=ZERO)
    cands = gen.sample(skeleton, pose, trans, viewmat, seed=11, n=1000, cfg=cfg)
    d = np.array([[c.camera.azimuth, c.camera.elevation, c.camera.log_distance] for c in cands])
    np.testing.assert_allclose(d.std(axis=0), [cfg.azimuth_sigma, cfg.elevation_sigma, cfg.distance_sigma], rtol=0.07)
    assert np.all(np.abs(d.mean(axis=0)) < 0.03)
    center = cands[0].center
    e0, d0 = _elevation_distance(viewmat, center)
    for c in cands[:50]:  # the recorded deltas are the ones applied
        e, dist = _elevation_distance(c.viewmat, center)
        assert e == pytest.approx(e0 + c.camera.elevation, abs=1e-9)
        assert dist == pytest.approx(d0 * math.exp(c.camera.log_distance), rel=1e-9)


def test_camera_keeps_looking_at_center_without_roll(skeleton, frame):
    pose, trans, viewmat = frame
    for c in gen.sample(skeleton, pose, trans, viewmat, seed=2, n=20):
        p = c.viewmat[:3, :3] @ c.center + c.viewmat[:3, 3]
        assert p[2] > 0 and np.abs(p[:2]).max() < 1e-9 * p[2]
        assert abs(c.viewmat[0, 2]) < 1e-9, "the camera's x axis stays horizontal"
        np.testing.assert_allclose(c.viewmat[:3, :3] @ c.viewmat[:3, :3].T, np.eye(3), atol=1e-12)


def test_off_center_camera_keeps_the_center_on_its_pixel_ray():
    center = np.array([0.1, 0.2, 1.0])
    viewmat = orbit_viewmat(center + [0.3, 0.0, 0.2], 0.4, 0.1, 2.5)
    before = viewmat[:3, :3] @ center + viewmat[:3, 3]
    after = gen.orbit_camera(viewmat, center, 0.7, -0.3, 0.2)
    p = after[:3, :3] @ center + after[:3, 3]
    np.testing.assert_allclose(p, before * math.exp(0.2), atol=1e-12)


def test_orbit_camera_matches_orbit_angles():
    center = np.array([0.5, -0.2, 1.1])
    for az, el, dist, d_az, d_el, d_log in [(0.0, 0.1, 3.0, 0.5, 0.2, 0.1), (2.0, -0.3, 1.5, -1.2, 0.6, -0.4)]:
        got = gen.orbit_camera(orbit_viewmat(center, az, el, dist), center, d_az, d_el, d_log)
        want = orbit_viewmat(center, az + d_az, el + d_el, dist * math.exp(d_log))
        np.testing.assert_allclose(got, want, atol=1e-12)


def test_camera_clamps():
    center = np.array([0.0, 0.0, 1.0])
    rng = np.random.default_rng(4)
    cfg = gen.GeneratorConfig(azimuth_sigma=1e6, elevation_sigma=1e6, distance_sigma=1e6)
    for el, dist in [(1.25, 3.0), (-1.0, 0.2), (1.45, 0.5)]:
        viewmat = orbit_viewmat(center, 0.3, el, dist)
        lo = max(dist / cfg.max_distance_ratio, min(dist, cfg.min_distance))
        for _ in range(100):
            out = gen.perturb_camera(viewmat, center, rng, cfg)
            assert np.isfinite(out).all()
            e, d = _elevation_distance(out, center)
            assert abs(e) <= max(cfg.max_elevation, abs(el)) + 1e-9
            assert lo - 1e-9 <= d <= dist * cfg.max_distance_ratio + 1e-9


@pytest.mark.parametrize("call, match", [
    (lambda sk, p, t, v: gen.sample(sk, p * np.nan, t, v, 0), r"pose: \d+ non-finite"),
    (lambda sk, p, t, v: gen.sample(sk, p[:-1], t, v, 0), r"pose: expected shape \[\.\.\., 18, 3\]"),
    (lambda sk, p, t, v: gen.sample(sk, p[None], t[None], v, 0), r"pose: expected one frame \[18, 3\]"),
    (lambda sk, p, t, v: gen.sample(sk, p, t[:2], v, 0), "trans: expected shape"),
    (lambda sk, p, t, v: gen.sample(sk, p, t, v[:3], 0), r"viewmat: expected shape \[4, 4\], got \[3, 4\]"),
    (lambda sk, p, t, v: gen.sample(sk, p, t, 2 * v, 0), "viewmat: expected a rigid"),
    (lambda sk, p, t, v: gen.sample(sk, p, t, v, -1), "seed: expected an integer >= 0"),
    (lambda sk, p, t, v: gen.sample(sk, p, t, v, 0, n=0), "n: expected an integer >= 1, got 0"),
    (lambda sk, p, t, v: gen.perturb_camera(v, [0, 0, np.inf], np.random.default_rng(0)), "center: expected 3 finite"),
    (lambda sk, p, t, v: gen.perturb_camera(v, camera_center(v), np.random.default_rng(0)), "center: the camera sits"),
])
def test_bad_input_is_named(skeleton, frame, call, match):
    with pytest.raises(ValueError, match=match):
        call(skeleton, *frame)


@pytest.mark.parametrize("kwargs, match", [
    ({"pose_sigma": {"arms": -0.1}}, r"pose_sigma\['arms'\]: must be a number in \[0, 1e\+06\], got -0.1"),
    ({"pose_sigma": {"arms": float("nan")}}, r"pose_sigma\['arms'\]: .* got nan"),
    ({"pose_sigma": {"tail": 0.1}}, r"pose_sigma: unknown group\(s\) \['tail'\]"),
    ({"max_angle": {"legs": 4.0}}, r"max_angle\['legs'\]: must lie in \(0, pi\], got 4.0"),
    ({"azimuth_sigma": -1.0}, "azimuth_sigma: must be a number"),
    ({"distance_sigma": float("inf")}, "distance_sigma: must be a number"),
    ({"max_elevation": 1.6}, r"max_elevation: must lie in \(0, pi/2\), got 1.6"),
    ({"max_distance_ratio": 0.5}, "max_distance_ratio: must be >= 1, got 0.5"),
    ({"min_distance": 0.0}, "min_distance: must be > 0, got 0.0"),
])
def test_bad_config_is_named(kwargs, match):
    with pytest.raises(ValueError, match=match):
        gen.GeneratorConfig(**kwargs)


def test_config_merges_partial_groups_with_defaults():
    cfg = gen.GeneratorConfig(pose_sigma={"arms": 0.3})
    assert cfg.pose_sigma == {**gen.DEFAULT_POSE_SIGMA, "arms": 0.3}
    assert cfg.max_angle == dict(gen.DEFAULT_MAX_ANGLE)


def test_keep_detail_drops_a_colour_shift_and_keeps_fine_detail():
    rng = np.random.default_rng(0)
    coarse = rng.uniform(0.2, 0.8, (2, 24, 20, 3)).astype(np.float32)
    shifted = gen.keep_detail(coarse, coarse + np.float32(0.1), sigma=3.0)
    np.testing.assert_allclose(shifted, coarse, atol=1e-6)  # a constant change is all low frequency
    checker = (np.indices((24, 20)).sum(0) % 2 * 2 - 1).astype(np.float32)[None, ..., None] * np.float32(0.05)
    kept = gen.keep_detail(coarse, coarse + checker, sigma=3.0) - coarse
    assert np.corrcoef(kept.ravel(), np.broadcast_to(checker, kept.shape).ravel())[0, 1] > 0.99
    assert np.abs(kept).mean() > 0.04  # the 1-pixel pattern passes nearly whole
    with pytest.raises(ValueError, match="refined: expected the coarse frames' shape"):
        gen.keep_detail(coarse, coarse[:1], sigma=3.0)
    with pytest.raises(ValueError, match="sigma: must be a finite number > 0"):
        gen.keep_detail(coarse, coarse, sigma=0.0)
