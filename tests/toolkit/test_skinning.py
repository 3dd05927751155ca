"""torch FK/LBS and rotations against the numpy references in trioman.runtime."""

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from tests.runtime.factories import random_mesh  # noqa: E402
from trioman.runtime.rotations import axis_angle_to_matrix as aa_np, matrix_to_quat as quat_np  # noqa: E402
from trioman.toolkit.body.skinning import apply_transforms, blend_transforms, skinning_transforms  # noqa: E402
from trioman.toolkit.rotations import axis_angle_to_matrix, matrix_to_quat, matrix_to_rot6d  # noqa: E402


@pytest.mark.parametrize("seed", range(3))
def test_torch_lbs_matches_numpy(seed):
    mesh = random_mesh(seed, J=9, V=50)
    rng = np.random.default_rng(seed)
    pose = rng.normal(size=(4, 9, 3))
    pose[1] = [np.pi - 1e-7, 0, 0]
    pose[2] = 1e-10
    trans = rng.normal(size=(4, 3))
    sk = mesh.skeleton
    A = skinning_transforms(sk.parents.tolist(), torch.from_numpy(sk.joints), torch.from_numpy(pose), torch.from_numpy(trans))
    np.testing.assert_allclose(A.numpy(), sk.skinning_transforms(pose, trans), atol=1e-12)
    T = blend_transforms(A, torch.from_numpy(mesh.skin_indices).long(), torch.from_numpy(mesh.skin_weights).double())
    v = apply_transforms(T, torch.from_numpy(mesh.vertices))
    np.testing.assert_allclose(v.numpy(), mesh.pose(pose, trans), atol=1e-6)  # float32 weights


def test_rotations_match_numpy_and_have_finite_gradients():
    rng = np.random.default_rng(0)
    aa = np.concatenate([rng.normal(size=(50, 3)), np.zeros((1, 3)), [[np.pi - 1e-6, 0, 0]], [[1e-9, 0, 0]]])
    t = torch.from_numpy(aa).requires_grad_(True)
    R = axis_angle_to_matrix(t)
    np.testing.assert_allclose(R.detach().numpy(), aa_np(aa), atol=1e-12)
    np.testing.assert_allclose(matrix_to_quat(R).detach().numpy(), quat_np(aa_np(aa)), atol=1e-9)
    (R.sum() + matrix_to_rot6d(R).sum()).backward()
    assert torch.isfinite(t.grad).all()
    assert torch.autograd.gradcheck(axis_angle_to_matrix, (torch.tensor([[1e-8, 0.0, 0.0], [0.3, -0.2, 1.0]], dtype=torch.float64, requires_grad=True),))
