"""The numpy FK + LBS (runtime) against Anny's own torch forward pass: the body-model parity test."""

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from trioman.toolkit.body.registry import create_body_model, list_body_models  # noqa: E402


def random_poses(J: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    pose = rng.normal(scale=0.6, size=(6, J, 3))
    axes = rng.normal(size=(J, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    pose[3] = axes * (np.pi - 1e-6)  # every joint near pi
    pose[4] = axes * 1e-9  # every joint tiny
    pose[5] = axes * rng.uniform(2.5, np.pi, size=(J, 1))  # large rotations everywhere
    trans = rng.normal(size=(6, 3))
    return pose, trans


def test_numpy_lbs_matches_anny(anny_body):
    mesh = anny_body.to_skinned_mesh()
    pose, trans = random_poses(anny_body.num_joints, 0)
    out = anny_body(torch.from_numpy(pose), torch.from_numpy(trans))
    err = np.abs(mesh.pose(pose, trans) - out.vertices.numpy()).max()
    assert err <= 1e-5, f"max vertex error {err:.3g} m"
    G = mesh.skeleton.forward_kinematics(pose, trans)
    np.testing.assert_allclose(G, out.joint_transforms.numpy(), atol=1e-9)
    A = mesh.skeleton.skinning_transforms(pose, trans)
    np.testing.assert_allclose(A, out.skinning_transforms.numpy(), atol=1e-9)


def test_zero_pose_gives_canonical_mesh(anny_body):
    J = anny_body.num_joints
    out = anny_body(torch.zeros(1, J, 3, dtype=torch.float64), torch.zeros(1, 3, dtype=torch.float64))
    np.testing.assert_allclose(out.vertices[0].numpy(), anny_body.canonical_vertices.numpy(), atol=1e-9)


def test_interface_shapes(anny_body):
    m = anny_body
    J, V = m.num_joints, m.canonical_vertices.shape[0]
    assert m.parents.shape == (J,) and int(m.parents[0]) == -1
    assert m.rest_joints.shape == (J, 3)
    assert m.faces.shape[1] == 3 and int(m.faces.max()) < V
    assert m.skin_indices.shape == m.skin_weights.shape and m.skin_indices.shape[0] == V
    assert m.uvs is not None and m.uv_faces.shape == m.faces.shape
    # z-up, metres: a standing adult between 1.4 and 2.1 m tall.
    height = float(m.canonical_vertices[:, 2].max() - m.canonical_vertices[:, 2].min())
    assert 1.4 < height < 2.1


def test_forward_is_differentiable(anny_body):
    pose = torch.zeros(1, anny_body.num_joints, 3, dtype=torch.float64, requires_grad=True)
    out = anny_body(pose, torch.zeros(1, 3, dtype=torch.float64))
    out.vertices.sum().backward()
    assert torch.isfinite(pose.grad).all() and pose.grad.abs().sum() > 0


def test_bad_inputs_are_named(anny_body):
    J = anny_body.num_joints
    with pytest.raises(ValueError, match=rf"pose: expected shape \[B, {J}, 3\]"):
        anny_body(torch.zeros(1, J - 1, 3), torch.zeros(1, 3))
    bad = torch.zeros(1, J, 3)
    bad[0, 5, 0] = float("nan")
    with pytest.raises(ValueError, match="pose: 1 non-finite"):
        anny_body(bad, torch.zeros(1, 3))
    with pytest.raises(ValueError, match="body_model: unknown body model 'smplq'"):
        create_body_model("smplq")
    with pytest.raises(ValueError, match="phenotype: height must lie in"):
        create_body_model("anny", phenotype={"height": 1.5})
    with pytest.raises(ValueError, match="phenotype: unknown key"):
        create_body_model("anny", phenotype={"shoe_size": 0.5})
    assert "anny" in list_body_models()
