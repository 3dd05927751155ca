"""The torch rotations against their numpy twins (trioman.runtime.rotations): same names, same values."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from trioman.runtime import rotations as np_rot  # noqa: E402
from trioman.toolkit import rotations as torch_rot  # noqa: E402


@pytest.mark.parametrize("name", ["axis_angle_to_matrix", "matrix_to_quat", "quat_to_matrix"])
def test_twins_agree(name):
    rng = np.random.default_rng(0)
    aa = rng.normal(size=(64, 3)) * np.array([[1.0]] * 32 + [[1e-8]] * 31 + [[0.0]])
    aa[:8] *= np.pi / np.linalg.norm(aa[:8], axis=1, keepdims=True)  # angles of exactly pi
    inputs = {"axis_angle_to_matrix": aa, "matrix_to_quat": np_rot.axis_angle_to_matrix(aa),
              "quat_to_matrix": np.concatenate([rng.normal(size=(63, 4)), np.zeros((1, 4))])}[name]
    want = getattr(np_rot, name)(inputs)
    got = getattr(torch_rot, name)(torch.from_numpy(inputs)).numpy()
    np.testing.assert_allclose(got, want, atol=1e-12)


def test_zero_quaternion_is_the_identity_with_finite_gradients():
    q = torch.zeros(2, 4, dtype=torch.float64, requires_grad=True)
    R = torch_rot.quat_to_matrix(q)
    R.sum().backward()
    assert torch.equal(R.detach(), torch.eye(3, dtype=torch.float64).expand(2, 3, 3))
    assert torch.isfinite(q.grad).all()
