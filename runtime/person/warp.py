"""The models' input crops, resampled as MediaPipe's ImageToTensorCalculator does, whatever OpenCV is installed.

MediaPipe 0.10.21 crops with OpenCV 4's ``warpPerspective`` (INTER_LINEAR) on the uint8 frame: each output
pixel's source point rounded to 1/32 pixel, the four neighbours weighted in 15-bit fixed point. OpenCV 5
resamples with other rounding, which moves the detector's keypoints by tenths of a pixel and the landmarks,
through the crop, by several (docs/fit.md); so the crop is computed here, in numpy, by OpenCV 4's rule
(modules/imgproc/src/imgwarp.cpp: WarpPerspectiveInvoker, remapBilinear, initInterTab2D).
"""

from __future__ import annotations

import math

import cv2
import numpy as np

INTER_BITS = 5  # the source point's fraction, in 1/32 pixel
INTER_TAB_SIZE = 1 << INTER_BITS
COEF_BITS = 15  # INTER_REMAP_COEF_BITS: the bilinear weights sum to 1 << 15


def crop_homography(center: tuple[float, float], side: float, rotation: float, size: int) -> np.ndarray:
    """[3, 3]: crop pixel -> frame point, for the square of ``side`` px about ``center`` turned by ``rotation``
    (radians) onto a ``size`` x ``size`` crop. Built as ImageToTensorConverterOpenCv builds it: the corners of
    the float32 ``cv::RotatedRect`` onto the crop's corners (``getPerspectiveTransform``), then inverted as
    ``warpPerspective`` inverts it."""
    corners = cv2.boxPoints(((center[0], center[1]), (side, side), rotation * 180.0 / math.pi))  # [4, 2] float32
    target = np.array([[0, size], [0, 0], [size, 0], [size, size]], np.float32)
    return cv2.invert(cv2.getPerspectiveTransform(corners, target))[1]


def warp_bilinear(image: np.ndarray,  # [H, W, C] uint8
                  matrix: np.ndarray,  # [3, 3] homography: output pixel (u, v) -> source point (x, y), OpenCV pixels
                  size: int,
                  replicate: bool,
                  ) -> np.ndarray:
    """``image`` resampled at the point ``matrix`` maps each output pixel to, for every output pixel of a ``size`` x ``size`` grid, as
    uint8 [size, size, C]; outside the frame the edge pixels repeat (``replicate``) or black comes in."""
    h, w = image.shape[:2]
    v, u = np.mgrid[0:size, 0:size].astype(np.float64)
    limit = float(np.iinfo(np.int32).max)
    wz = matrix[2, 0] * u + matrix[2, 1] * v + matrix[2, 2]
    wz = np.divide(INTER_TAB_SIZE, wz, out=np.zeros_like(wz), where=wz != 0)
    fixed = [np.clip(np.rint((matrix[i, 0] * u + matrix[i, 1] * v + matrix[i, 2]) * wz), -limit, limit).astype(np.int64)
             for i in (0, 1)]  # [size, size] in 1/32 px, rounded half to even as cvRound
    (x0, y0), (fx, fy) = [f >> INTER_BITS for f in fixed], [f & (INTER_TAB_SIZE - 1) for f in fixed]
    if replicate:
        source, lo, xs, ys = image, 0, (w - 1), (h - 1)
    else:  # one black pixel around the frame: every neighbour outside it reads black
        source, lo, xs, ys = np.pad(image, ((1, 1), (1, 1), (0, 0))), -1, w, h
    off = -lo

    def pixel(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return source[np.clip(y, lo, ys) + off, np.clip(x, lo, xs) + off].astype(np.int64)  # [size, size, C]

    # initInterTab2D: the product of the 1-D weights (1 - f, f) at f = k / 32, times 1 << 15, exact integers.
    scale = (1 << COEF_BITS) // (INTER_TAB_SIZE * INTER_TAB_SIZE)
    wx1, wy1 = fx[..., None], fy[..., None]
    wx0, wy0 = INTER_TAB_SIZE - wx1, INTER_TAB_SIZE - wy1
    total = (pixel(x0, y0) * (wx0 * wy0) + pixel(x0 + 1, y0) * (wx1 * wy0)
             + pixel(x0, y0 + 1) * (wx0 * wy1) + pixel(x0 + 1, y0 + 1) * (wx1 * wy1)) * scale
    return np.clip((total + (1 << (COEF_BITS - 1))) >> COEF_BITS, 0, 255).astype(np.uint8)
