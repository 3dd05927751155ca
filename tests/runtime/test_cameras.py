"""Camera helpers: framing keeps every point in view from any orbit angle."""

from __future__ import annotations

import numpy as np
import pytest

from trioman.runtime.cameras import camera_center, frame_points, project


@pytest.mark.parametrize("az, el", [(0, 0), (90, 10), (200, -20), (330, 60)])
def test_frame_points_keeps_points_in_view(az, el):
    pts = np.random.default_rng(1).normal([0.3, -1.0, 0.9], [0.3, 1.2, 0.5], (500, 3))
    K, viewmat, center = frame_points(pts, (320, 240), np.deg2rad(az), np.deg2rad(el), fill=0.9)
    uv, z = project(pts, viewmat, K)
    assert np.all(z > 0)
    assert np.all((uv >= 0) & (uv <= [320, 240]))
    # looks at the centre: it projects to the principal point
    c_uv, _ = project(center[None], viewmat, K)
    np.testing.assert_allclose(c_uv[0], [160, 120], atol=1e-6)
    # a full-ish fill: the farthest point reaches well beyond half the allowed radius
    assert np.abs(uv - [160, 120]).max() > 0.3 * 120
    assert np.linalg.norm(camera_center(viewmat) - center) > 0


def test_frame_points_errors():
    with pytest.raises(ValueError, match="points: need finite points"):
        frame_points(np.full((3, 3), np.nan), (8, 8), 0, 0)
    with pytest.raises(ValueError, match="fill: must lie in"):
        frame_points(np.zeros((3, 3)), (8, 8), 0, 0, fill=2)


def test_frame_points_frames_the_bulk_despite_one_far_outlier():
    # issue 18, case 7: one Gaussian at 100 m used to shrink the body to a dot
    pts = np.random.default_rng(1).normal([0.3, -1.0, 0.9], [0.3, 0.3, 0.5], (5000, 3))
    K, viewmat, _ = frame_points(pts, (320, 240), 0.3, 0.1)
    K_out, viewmat_out, _ = frame_points(np.concatenate([pts, [[100.0, 0.0, 0.0]]]), (320, 240), 0.3, 0.1)
    np.testing.assert_allclose(K_out, K, rtol=0.05)
    uv, z = project(pts, viewmat_out, K_out)
    assert np.all(z > 0) and np.mean((uv >= 0).all(1) & (uv <= [320, 240]).all(1)) > 0.999


def test_frame_points_refuses_points_too_far_to_render_and_non_finite_cameras():
    with pytest.raises(ValueError, match=r"points: 1e\+30 m from the origin, too far for their 0\.05 m extent"):
        frame_points(np.random.default_rng(0).normal(size=(50, 3)) + 1e30, (8, 8), 0, 0)
    from trioman.runtime.cameras import look_at

    with pytest.raises(ValueError, match=r"eye: camera position \[nan, 0\.0, 0\.0\] or target .* is not finite"):
        look_at(np.array([np.nan, 0.0, 0.0]), np.zeros(3))
