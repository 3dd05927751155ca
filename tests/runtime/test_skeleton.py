import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tests.runtime.factories import random_mesh
from trioman.runtime.rotations import axis_angle_to_matrix
from trioman.runtime.skeleton import SkinnedMesh


def brute_force_pose(mesh: SkinnedMesh, pose: np.ndarray, trans: np.ndarray) -> np.ndarray:
    """Per-vertex loop: walk each joint's chain from the root, compose 4x4s, blend."""
    sk = mesh.skeleton

    def world(j):
        chain = []
        while j >= 0:
            chain.append(j)
            j = sk.parents[j]
        G = np.eye(4)
        for c in reversed(chain):
            L = np.eye(4)
            L[:3, :3] = axis_angle_to_matrix(pose[c])
            L[:3, 3] = sk.joints[c] + trans if c == 0 else sk.joints[c] - sk.joints[sk.parents[c]]
            G = G @ L
        return G

    out = np.zeros((mesh.num_vertices, 3))
    for v in range(mesh.num_vertices):
        for j, w in zip(mesh.skin_indices[v], mesh.skin_weights[v]):
            A = world(j) @ np.block([[np.eye(3), -sk.joints[j][:, None]], [np.zeros((1, 3)), np.ones((1, 1))]])
            out[v] += w * (A[:3, :3] @ mesh.vertices[v] + A[:3, 3])
    return out


@pytest.mark.parametrize("seed", range(5))
def test_lbs_matches_brute_force(seed):
    mesh = random_mesh(seed)
    rng = np.random.default_rng(100 + seed)
    pose = rng.normal(size=(mesh.skeleton.num_joints, 3))
    pose[1] = [np.pi - 1e-7, 0, 0]  # near pi
    pose[2] = [1e-10, -1e-10, 0]  # tiny
    trans = rng.normal(size=3)
    np.testing.assert_allclose(mesh.pose(pose, trans), brute_force_pose(mesh, pose, trans), atol=1e-10)


def test_zero_pose_is_rest_and_batching():
    mesh = random_mesh(7)
    J = mesh.skeleton.num_joints
    np.testing.assert_allclose(mesh.pose(np.zeros((J, 3)), np.zeros(3)), mesh.vertices, atol=1e-6)
    rng = np.random.default_rng(0)
    pose, trans = rng.normal(size=(2, 19, J, 3)), rng.normal(size=(2, 19, 3))
    batched = mesh.pose(pose, trans, chunk=4)
    assert batched.shape == (2, 19, mesh.num_vertices, 3)
    np.testing.assert_allclose(batched[1, 17], mesh.pose(pose[1, 17], trans[1, 17]), atol=1e-12)


def test_arrays_round_trip():
    mesh = random_mesh(3)
    back = SkinnedMesh.from_arrays(mesh.to_arrays())
    for key, value in mesh.to_arrays().items():
        np.testing.assert_array_equal(back.to_arrays()[key], value)
    assert all(a.dtype != object for a in mesh.to_arrays().values())


@pytest.mark.parametrize(
    "mutate, field",
    [
        (lambda a: a.pop("faces"), "faces: missing"),
        (lambda a: a.__setitem__("parents", np.array([0] + list(a["parents"][1:]))), "parents"),
        (lambda a: a.__setitem__("joints", a["joints"][:-1]), "joints: expected shape"),
        (lambda a: a["vertices"].__setitem__((0, 0), np.nan), "vertices: 1 non-finite"),
        (lambda a: a["faces"].__setitem__((0, 0), 10_000), "faces: indices"),
        (lambda a: a["skin_indices"].__setitem__((0, 0), 99), "skin_indices: joint indices"),
        (lambda a: a["skin_weights"].__setitem__((0, 0), 5.0), "skin_weights: rows must sum to 1, vertex 0"),
        (lambda a: a.__setitem__("joint_names", np.arange(7)), "joint_names"),
    ],
)
def test_validation_names_the_field(mutate, field):
    arrays = {k: v.copy() for k, v in random_mesh(0).to_arrays().items()}
    mutate(arrays)
    with pytest.raises(ValueError, match=field):
        SkinnedMesh.from_arrays(arrays)


def test_pose_errors_name_the_field():
    mesh = random_mesh(0)
    J = mesh.skeleton.num_joints
    with pytest.raises(ValueError, match=r"pose: expected shape \[\.\.\., 7, 3\]"):
        mesh.pose(np.zeros((J + 1, 3)), np.zeros(3))
    with pytest.raises(ValueError, match="trans: expected shape"):
        mesh.pose(np.zeros((J, 3)), np.zeros(2))
    bad = np.zeros((J, 3))
    bad[3, 1] = np.inf
    with pytest.raises(ValueError, match="pose: 1 non-finite"):
        mesh.pose(bad, np.zeros(3))
    with pytest.raises(ValueError, match="unknown joint name 'elbow'"):
        mesh.skeleton.index("elbow")


@settings(max_examples=50, deadline=None)
@given(st.floats(-1e4, 1e4), st.floats(-1e3, 1e3))
def test_extreme_angles_and_translations_stay_finite_and_rigid(angle, t):
    mesh = random_mesh(1)
    J = mesh.skeleton.num_joints
    pose = np.zeros((J, 3))
    pose[:, 2] = angle
    out = mesh.pose(pose, np.full(3, t))
    assert np.all(np.isfinite(out))
    # A pure root motion is rigid: pairwise distances of the root-only vertices are preserved.
    pose_root = np.zeros((J, 3))
    pose_root[0] = [angle, 0, 0]
    moved = mesh.pose(pose_root, np.full(3, t))
    d0 = np.linalg.norm(mesh.vertices[0] - mesh.vertices[1])
    d1 = np.linalg.norm(moved[0] - moved[1])
    assert abs(d0 - d1) < 1e-6 * max(1.0, abs(t))


def test_pose_correctives_move_the_rest_mesh_before_skinning():
    """SMPL-style pose blend shapes: v = LBS(v_rest + sum_p f_p P_p), f = flatten(R_j - I, j >= 1)."""
    import dataclasses

    mesh = random_mesh(5)
    rng = np.random.default_rng(6)
    J, V = mesh.skeleton.num_joints, mesh.num_vertices
    P = rng.normal(scale=0.01, size=(9 * (J - 1), V, 3)).astype(np.float32)
    corrected = dataclasses.replace(mesh, pose_correctives=P)
    pose, trans = rng.normal(size=(2, J, 3)), rng.normal(size=(2, 3))
    f = (axis_angle_to_matrix(pose[:, 1:]) - np.eye(3)).reshape(2, -1)
    for i in range(2):
        moved = dataclasses.replace(mesh, vertices=mesh.vertices + np.einsum("p,pvk->vk", f[i], P.astype(np.float64)))
        np.testing.assert_allclose(corrected.pose(pose[i], trans[i]), moved.pose(pose[i], trans[i]), atol=1e-6)
    np.testing.assert_allclose(corrected.pose(np.zeros((J, 3)), np.zeros(3)), mesh.vertices, atol=1e-12)
    again = SkinnedMesh.from_arrays(corrected.to_arrays())
    np.testing.assert_array_equal(again.pose_correctives, P)
    with pytest.raises(ValueError, match=r"pose_correctives: expected shape \[54, 40, 3\]"):
        dataclasses.replace(mesh, pose_correctives=P[:, :, :2])
