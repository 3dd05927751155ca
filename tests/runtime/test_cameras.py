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
