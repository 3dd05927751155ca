import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from trioman.runtime.rotations import (
    axis_angle_to_matrix,
    matrix_to_axis_angle,
    matrix_to_quat,
    quat_to_axis_angle,
    quat_to_matrix,
)


def rodrigues_reference(aa: np.ndarray) -> np.ndarray:
    """exp of the skew matrix by a long Taylor series in float64 (independent of the closed form)."""
    x, y, z = aa
    K = np.array([[0, -z, y], [z, 0, -x], [-y, x, 0]])
    R, term = np.eye(3), np.eye(3)
    for k in range(1, 60):
        term = term @ K / k
        R = R + term
    return R


@pytest.mark.parametrize("angle", [0.0, 1e-12, 1e-7, 1e-3, 0.5, 2.0, np.pi - 1e-6, np.pi])
def test_axis_angle_matches_series(angle):
    rng = np.random.default_rng(0)
    axis = rng.normal(size=3)
    aa = axis / np.linalg.norm(axis) * angle
    np.testing.assert_allclose(axis_angle_to_matrix(aa), rodrigues_reference(aa), atol=1e-12)


def test_round_trip_batched_near_pi_and_tiny():
    rng = np.random.default_rng(1)
    axes = rng.normal(size=(500, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angles = np.concatenate([rng.uniform(0, np.pi - 1e-3, 400), np.pi - 10.0 ** -rng.uniform(4, 9, 50), 10.0 ** -rng.uniform(4, 12, 50)])
    aa = axes * angles[:, None]
    R = axis_angle_to_matrix(aa)
    np.testing.assert_allclose(R @ np.swapaxes(R, -1, -2), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    np.testing.assert_allclose(axis_angle_to_matrix(matrix_to_axis_angle(R)), R, atol=1e-9)


def test_quaternion_paths_agree():
    rng = np.random.default_rng(2)
    aa = rng.normal(size=(100, 3))
    R = axis_angle_to_matrix(aa)
    q = matrix_to_quat(R)
    np.testing.assert_allclose(np.linalg.norm(q, axis=-1), 1.0, atol=1e-12)
    np.testing.assert_allclose(quat_to_matrix(q), R, atol=1e-12)
    np.testing.assert_allclose(axis_angle_to_matrix(quat_to_axis_angle(q)), R, atol=1e-12)


def test_zero_quaternion_is_identity():
    np.testing.assert_array_equal(quat_to_matrix(np.zeros(4)), np.eye(3))


def test_float32_in_float32_out():
    assert axis_angle_to_matrix(np.zeros((2, 3), np.float32)).dtype == np.float32


def test_bad_shape_names_axis_angle():
    with pytest.raises(ValueError, match="axis-angle"):
        axis_angle_to_matrix(np.zeros((4, 2)))


@settings(max_examples=200, deadline=None)
@given(arrays(np.float64, 3, elements=st.floats(-1e6, 1e6, allow_nan=False)))
def test_extreme_angles_stay_rotations(aa):
    R = axis_angle_to_matrix(aa)
    assert np.all(np.isfinite(R))
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-8)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-8)
