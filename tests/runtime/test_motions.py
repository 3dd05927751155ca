import numpy as np
import pytest

from tests.runtime.factories import JOINTS, NAMES, PARENTS
from trioman.runtime import motions
from trioman.runtime.skeleton import Skeleton


@pytest.fixture
def skeleton():
    return Skeleton(tuple(NAMES), np.array(PARENTS), JOINTS)


@pytest.mark.parametrize("make", [motions.turn_in_place, *motions.TEST_MOTIONS.values()])
def test_motion_shapes_finite_and_grounded(skeleton, make):
    m = make(skeleton, 24)
    assert m.pose.shape == (24, len(NAMES), 3) and m.trans.shape == (24, 3)
    assert np.all(np.isfinite(m.pose)) and np.all(np.isfinite(m.trans))
    G = skeleton.forward_kinematics(m.pose, m.trans)
    feet = [NAMES.index("foot.L"), NAMES.index("foot.R")]
    np.testing.assert_allclose(G[:, feet, 2, 3].min(axis=1), JOINTS[feet, 2].min(), atol=1e-9)
    assert np.ptp(m.pose, axis=0).max() > 0.05, "the motion should move"


def test_turn_goes_all_the_way_round(skeleton):
    m = motions.turn_in_place(skeleton, 40)
    yaw = m.pose[:, 0, 2]
    assert yaw[0] == 0 and yaw[-1] == pytest.approx(2 * np.pi * 39 / 40)


def test_arms_raised_lifts_wrists_above_head(skeleton):
    m = motions.arms_raised(skeleton, 10)
    G = skeleton.forward_kinematics(m.pose[-1], m.trans[-1])
    assert G[NAMES.index("lowerarm01.L"), 2, 3] > G[NAMES.index("head"), 2, 3]


def test_missing_joint_and_bad_frames_are_named(skeleton):
    small = Skeleton(("root", "head"), np.array([-1, 0]), np.zeros((2, 3)))
    with pytest.raises(ValueError, match="unknown joint name 'upperarm01.L'"):
        motions.arms_raised(small, 4)
    with pytest.raises(ValueError, match="frames: must be >= 1"):
        motions.squat(skeleton, 0)


@pytest.mark.parametrize("name", sorted(motions.MOTIONS))
def test_shipped_motions_are_finite_named_and_move(skeleton, name):
    m = motions.MOTIONS[name](skeleton, motions.DEFAULT_FRAMES[name])
    assert m.joint_names == tuple(NAMES) and m.fps == motions.DEFAULT_FPS
    assert m.pose.shape == (motions.DEFAULT_FRAMES[name], len(NAMES), 3)
    assert np.all(np.isfinite(m.pose)) and np.all(np.isfinite(m.trans))
    assert np.ptp(m.pose, axis=0).max() > 0.1
    # no joint flips between frames (smooth, continuous motions)
    assert np.abs(np.diff(m.pose, axis=0)).max() < 0.5


def test_walk_moves_forward_and_jump_leaves_the_ground(skeleton):
    w = motions.walk(skeleton, 60)
    assert w.trans[-1, 1] < -1.5  # forward is -y; 2 s at 1.1 m/s
    j = motions.jump(skeleton, 45, height=0.35)
    G = skeleton.forward_kinematics(j.pose, j.trans)
    feet = [NAMES.index("foot.L"), NAMES.index("foot.R")]
    lift = G[:, feet, 2, 3].min(axis=1) - JOINTS[feet, 2].min()
    assert lift.max() > 0.3 and abs(lift[0]) < 1e-9 and abs(lift[-1]) < 0.01


def test_for_skeleton_matches_joints_by_name(skeleton):
    m = motions.wave(skeleton, 5)
    order = np.random.default_rng(0).permutation(len(NAMES))
    shuffled = motions.Motion("w", m.pose[:, order], m.trans, tuple(NAMES[i] for i in order))
    back = shuffled.for_skeleton(skeleton)
    np.testing.assert_array_equal(back.pose, m.pose)
    partial = motions.Motion("p", m.pose[:, :3], m.trans, tuple(NAMES[:3])).for_skeleton(skeleton)
    np.testing.assert_array_equal(partial.pose[:, 3:], 0.0)  # joints the motion does not name stay at rest
    with pytest.raises(ValueError, match="joint_names: 1 joint.*'tail'"):
        motions.Motion("x", m.pose[:, :2], m.trans, ("root", "tail")).for_skeleton(skeleton)
    with pytest.raises(ValueError, match="pose: motion 'y' has 2 joints"):
        motions.Motion("y", m.pose[:, :2], m.trans).for_skeleton(skeleton)
