"""The viewer's posing in numpy: bends per joint group (mirrored on the right side), the motion
catalog, and the splat arrays that changed."""

import numpy as np
import pytest

from tests.runtime.viewer.helpers import make_avatar
from trioman.runtime.avatar import Gaussians
from trioman.runtime.motions import Motion
from trioman.runtime.rotations import axis_angle_to_matrix, matrix_to_quat, quat_to_matrix
from trioman.runtime.viewer.posing import PoseControls, Poser, SplatDiff, bend_pose, covariances, group_bases, is_right


def test_right_side_names():
    assert [is_right(n) for n in ("upperarm01.R", "right_elbow", "r_hip", "upperarm01.L", "left_knee", "spine01",
                                  "hand_r", "root")] == [True, True, True, False, False, False, True, False]


def test_a_bend_turns_the_base_joints_of_its_group_and_mirrors_the_right_side():
    groups = ("root", "arms", "arms", "legs", "arms")
    bases = group_bases(groups, np.array([-1, 0, 0, 0, 1]))
    np.testing.assert_array_equal(bases, [True, True, True, True, False])  # joint 4 hangs from an arm joint
    right = np.array([False, False, True, False, False])
    base = np.zeros((5, 3))
    base[1] = [0.0, 0.0, 0.4]
    out = bend_pose(base, groups, bases, right, {"arms": 30.0})
    a = np.deg2rad(30.0)
    np.testing.assert_allclose(axis_angle_to_matrix(out[1]), axis_angle_to_matrix([0, a, 0]) @ axis_angle_to_matrix(base[1]),
                               atol=1e-12)
    np.testing.assert_allclose(out[2], [0, -a, 0], atol=1e-12)  # mirrored about x = 0
    np.testing.assert_array_equal(out[[0, 3, 4]], 0)
    with pytest.raises(ValueError, match=r"bends: unknown group\(s\) \['wings'\]"):
        bend_pose(base, groups, bases, right, {"wings": 1.0})
    with pytest.raises(ValueError, match=r"bends\['arms'\]: must be finite degrees in \[-180, 180\], got nan"):
        bend_pose(base, groups, bases, right, {"arms": float("nan")})


def test_rest_pose_and_frames(tmp_path):
    avatar = make_avatar(tmp_path / "a")
    J = avatar.skeleton.num_joints
    poser = Poser(avatar, {"m": Motion("m", np.full((2, J, 3), 0.1, np.float32), np.array([[0, 0, 0], [0, 0, 1]], np.float32))})
    pose, trans = poser.pose(PoseControls(frame=1))
    np.testing.assert_allclose(pose, 0.1, rtol=1e-6)
    np.testing.assert_allclose(trans, [0, 0, 1])
    pose, trans = poser.pose(PoseControls(frame=1, rest=True))
    assert not pose.any() and not trans.any()
    with pytest.raises(ValueError, match=r"frame: 5 is out of range for 'm' \(2 frames\)"):
        poser.pose(PoseControls(frame=5))
    with pytest.raises(ValueError, match=r"motion: unknown entry 'x'"):
        poser.select("x")


def test_splat_diff_sends_what_changed():
    rng = np.random.default_rng(0)
    N = 5
    q = matrix_to_quat(axis_angle_to_matrix(rng.normal(size=(N, 3))))
    s = rng.uniform(0.01, 0.1, (N, 3))
    R = quat_to_matrix(q)
    np.testing.assert_allclose(covariances(q, s), np.einsum("nij,nj,nkj->nik", R, s**2, R), rtol=1e-5)
    iso = covariances(np.tile([1.0, 0, 0, 0], (N, 1)), s)
    np.testing.assert_allclose(iso, np.einsum("nj,ij->nij", s**2, np.eye(3)), rtol=1e-6)
    g = Gaussians(rng.normal(size=(N, 3)).astype(np.float32), q.astype(np.float32), s.astype(np.float32),
                  np.ones(N, np.float32), rng.random((N, 3)).astype(np.float32))
    diff = SplatDiff()
    assert {k: v.shape for k, v in diff.update(g).items()} == {
        "centers": (N, 3), "covariances": (N, 3, 3), "rgbs": (N, 3), "opacities": (N, 1)}
    assert diff.update(g) == {}
    moved = g._replace(means=g.means + 1)
    assert set(diff.update(moved)) == {"centers"}
    assert set(diff.update(moved._replace(scales=2 * moved.scales, colors=moved.colors / 2))) == {"covariances", "rgbs"}
