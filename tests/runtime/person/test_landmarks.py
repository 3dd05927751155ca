"""The crop geometry and the resampling of the landmark stage on synthetic inputs: the region of interest from
two points, the crop <-> frame maps, OpenCV 4's fixed-point bilinear warp, the heatmap refinement."""

import math

import numpy as np
import pytest

from trioman.runtime.person.landmarks import Roi, crop_matrix, estimate, normalize_radians, refine_from_heatmap, roi_from_points
from trioman.runtime.person.warp import box_points, crop_homography, warp_bilinear


def test_roi_from_points():
    # The scale point straight above the centre: no rotation, side 2 * 1.25 * distance.
    roi = roi_from_points(np.array([100.0, 200.0]), np.array([100.0, 120.0]))
    assert roi.center == (100.0, 200.0) and roi.size == pytest.approx(200.0) and roi.rotation == pytest.approx(0.0)
    # To the right of it: the body lies along +x, the crop turns by +90 degrees (clockwise on screen).
    assert roi_from_points(np.array([0.0, 0.0]), np.array([10.0, 0.0])).rotation == pytest.approx(math.pi / 2)
    assert normalize_radians(3 * math.pi / 2) == pytest.approx(-math.pi / 2)
    assert -math.pi <= normalize_radians(math.pi) < math.pi


def test_crop_maps_agree():
    roi = Roi((300.0, 200.0), 120.0, 0.4)
    m = crop_matrix(roi)  # crop px -> frame px
    np.testing.assert_allclose(m @ [128, 128, 1], roi.center, atol=1e-9)
    # The crop's up direction (-v) points along the turned frame axis: R(0.4) (0, -1).
    up = m @ [128, 0, 1] - m @ [128, 128, 1]
    np.testing.assert_allclose(up, 60 * np.array([math.sin(0.4), -math.cos(0.4)]), atol=1e-9)
    h = crop_homography(roi.center, roi.size, roi.rotation, 256)
    for u, v in ((0, 0), (256, 0), (17, 200)):
        p = h @ [u, v, 1]
        np.testing.assert_allclose(p[:2] / p[2], m @ [u, v, 1], atol=1e-3)  # float32 corners in the homography
    np.testing.assert_allclose(crop_matrix(roi, size=1) @ [0.5, 0.5, 1], roi.center)


def test_box_points_are_opencv4s():
    # OpenCV 4.10's cv2.boxPoints (the one MediaPipe 0.10.21 links) for the astronaut's crop; OpenCV 5.1's gives
    # [878.1895751953125, 4.598228454589844] and [678.1428833007812, 1243.4722900390625] for the last two corners.
    corners = box_points((158.72918701171875, 524.0119018554688), 1254.92138671875, 0.16009271144866943)
    assert corners.dtype == np.float32
    assert corners.tolist() == [[-560.7311401367188, 1043.4256591796875], [-360.6844787597656, -195.44845581054688],
                                [878.1895141601562, 4.59814453125], [678.142822265625, 1243.4722900390625]]
    axis = box_points((10.0, 20.0), 8.0, 0.0)  # unturned: bottom-left, top-left, top-right, bottom-right
    assert axis.tolist() == [[6, 24], [6, 16], [14, 16], [14, 24]]


def reference_warp(image: np.ndarray, matrix: np.ndarray, size: int, replicate: bool) -> np.ndarray:
    """OpenCV 4's warpPerspective (INTER_LINEAR) in numpy, the oracle of warp_bilinear: the source point rounded
    to 1/32 px, the four neighbours weighted (32 - f)(32 - g) ... times 32 (sum 1 << 15), rounded half up."""
    h, w = image.shape[:2]
    v, u = np.mgrid[0:size, 0:size].astype(np.float64)
    wz = matrix[2, 0] * u + matrix[2, 1] * v + matrix[2, 2]
    x, y = [np.rint((matrix[i, 0] * u + matrix[i, 1] * v + matrix[i, 2]) * 32 / wz).astype(np.int64) for i in (0, 1)]
    x0, y0, fx, fy = x >> 5, y >> 5, (x & 31)[..., None], (y & 31)[..., None]
    padded = np.pad(image, ((1, 1), (1, 1), (0, 0)), mode="edge" if replicate else "constant").astype(np.int64)

    def pixel(px, py):
        lo = 0 if replicate else -1
        return padded[np.clip(py, lo, h - 1 - lo) + 1, np.clip(px, lo, w - 1 - lo) + 1]

    total = 32 * (pixel(x0, y0) * (32 - fx) * (32 - fy) + pixel(x0 + 1, y0) * fx * (32 - fy)
                  + pixel(x0, y0 + 1) * (32 - fx) * fy + pixel(x0 + 1, y0 + 1) * fx * fy)
    return ((total + (1 << 14)) >> 15).astype(np.uint8)


def test_warp_bilinear_matches_the_numpy_oracle():
    rng = np.random.default_rng(1)
    for image in (rng.integers(0, 256, (97, 61, 3), dtype=np.uint8), rng.integers(0, 256, (40, 300, 3), dtype=np.uint8)):
        h, w = image.shape[:2]
        for _ in range(10):
            centre = (float(rng.uniform(-50, w + 50)), float(rng.uniform(-50, h + 50)))
            matrix = crop_homography(centre, float(rng.uniform(5, 800)), float(rng.uniform(-4, 4)), 64)
            for replicate in (True, False):
                np.testing.assert_array_equal(warp_bilinear(image, matrix, 64, replicate),
                                              reference_warp(image, matrix, 64, replicate))


def test_warp_bilinear_fixed_point():
    rng = np.random.default_rng(0)
    image = rng.integers(0, 256, (40, 50, 3), dtype=np.uint8)
    shift = np.array([[1.0, 0, 3], [0, 1, 2], [0, 0, 1]])  # an integer shift copies pixels
    np.testing.assert_array_equal(warp_bilinear(image, shift, 30, replicate=True), image[2:32, 3:33])
    # Half a pixel to the right: weights 16/32 each in 15-bit fixed point, rounded half up.
    half = warp_bilinear(image, np.array([[1.0, 0, 0.5], [0, 1, 0], [0, 0, 1]]), 30, replicate=True)
    a, b = image[:30, :30].astype(int), image[:30, 1:31].astype(int)
    np.testing.assert_array_equal(half, (a * 16384 + b * 16384 + 16384) >> 15)
    # Outside the frame: edge pixels (replicate) or black, mixed in over the last pixel.
    far = np.array([[1.0, 0, -100], [0, 1, 0], [0, 0, 1]])
    np.testing.assert_array_equal(warp_bilinear(image, far, 10, replicate=True)[:, :10], np.repeat(image[:10, :1], 10, 1))
    assert not warp_bilinear(image, far, 10, replicate=False).any()
    edge = warp_bilinear(image, np.array([[1.0, 0, -0.5], [0, 1, 0], [0, 0, 1]]), 4, replicate=False)
    np.testing.assert_array_equal(edge[:, 0], (image[:4, 0].astype(int) * 16384 + 16384) >> 15)


def test_refine_from_heatmap():
    heat = np.full((64, 64, 3), -20.0, np.float32)  # sigmoid ~ 0: nothing to refine towards
    heat[10, 20, 0] = heat[10, 22, 0] = 20.0  # two peaks: the mean cell (21, 10) in cell units
    heat[40, 40, 1] = 0.0  # peak 0.5 reaches min_confidence_to_refine; the window's other cells weigh ~0
    points = np.array([[21.3 / 64, 10.6 / 64], [40.9 / 64, 40.2 / 64], [-0.5, 0.5]])
    out = refine_from_heatmap(points, heat)
    np.testing.assert_allclose(out[0], [21 / 64, 10 / 64], atol=1e-6)
    np.testing.assert_allclose(out[1], [40 / 64, 40 / 64], atol=1e-6)
    np.testing.assert_array_equal(out[2], points[2])  # off the heatmap: kept
    heat[40, 40, 1] = -0.1  # below 0.5: kept
    np.testing.assert_array_equal(refine_from_heatmap(points, heat)[1], points[1])


def test_estimate_rejects_a_bad_roi(models):
    image = np.zeros((64, 64, 3), np.uint8)
    for roi in (Roi((10.0, 10.0), 0.0, 0.0), Roi((float("nan"), 10.0), 20.0, 0.0), Roi((10.0, 10.0), 20.0, float("inf"))):
        with pytest.raises(ValueError, match=r"^roi: expected a finite centre and rotation and a side > 0"):
            estimate(models.landmarks, image, roi)
