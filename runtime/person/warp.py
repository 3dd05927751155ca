"""The models' input crops, resampled as MediaPipe's ImageToTensorCalculator does, whatever OpenCV is installed.

MediaPipe 0.10.21 crops with OpenCV 4's ``warpPerspective`` (INTER_LINEAR) on the uint8 frame: each output
pixel's source point rounded to 1/32 pixel, the four neighbours weighted in 15-bit fixed point. OpenCV 5's
``warpAffine``/``warpPerspective`` resample with other rounding, which moves the detector's keypoints by
tenths of a pixel and the landmarks, through the crop, by several (docs/fit.md); so the source points are
rounded here by OpenCV 4's rule (modules/imgproc/src/imgwarp.cpp: WarpPerspectiveInvoker, remapBilinear,
initInterTab2D), the same bytes under OpenCV 4.10 and 5.1.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

INTER_BITS = 5  # the source point's fraction, in 1/32 pixel
INTER_TAB_SIZE = 1 << INTER_BITS


def box_points(center: tuple[float, float], side: float, rotation: float) -> np.ndarray:
    """The corners of MediaPipe's ``cv::RotatedRect(center, (side, side), rotation * 180.f / M_PI)``: [4, 2]
    float32, bottom-left, top-left, top-right, bottom-right of the turned square. OpenCV 4's
    ``RotatedRect::points`` in float32 arithmetic, term by term (modules/core/src/types.cpp); OpenCV 5's
    ``boxPoints`` rounds the last two corners otherwise, which moves the crop's rounding."""
    f = np.float32
    cx, cy, s = f(center[0]), f(center[1]), f(side)
    angle = f(f(f(rotation) * f(180.0)) / math.pi)  # degrees, as the ImageToTensor converter passes them
    radians = float(angle) * math.pi / 180.0
    b = f(f(math.cos(radians)) * f(0.5))
    a = f(f(math.sin(radians)) * f(0.5))
    p0 = (cx - a * s - b * s, cy + b * s - a * s)
    p1 = (cx + a * s - b * s, cy - b * s - a * s)
    p2 = (f(2) * cx - p0[0], f(2) * cy - p0[1])
    p3 = (f(2) * cx - p1[0], f(2) * cy - p1[1])
    return np.array([p0, p1, p2, p3], np.float32)


def crop_homography(center: tuple[float, float], side: float, rotation: float, size: int) -> np.ndarray:
    """[3, 3]: crop pixel -> frame point, for the square of ``side`` px about ``center`` turned by ``rotation``
    (radians) onto a ``size`` x ``size`` crop. Built as ImageToTensorConverterOpenCv builds it: the corners
    (``box_points``) onto the crop's corners (``getPerspectiveTransform``), then inverted as
    ``warpPerspective`` inverts it."""
    target = np.array([[0, size], [0, 0], [size, 0], [size, size]], np.float32)
    return cv2.invert(cv2.getPerspectiveTransform(box_points(center, side, rotation), target))[1]


def warp_bilinear(image: np.ndarray,  # [H, W, C] uint8
                  matrix: np.ndarray,  # [3, 3] homography: output pixel (u, v) -> source point (x, y), OpenCV pixels
                  size: int,
                  replicate: bool,
                  ) -> np.ndarray:
    """``image`` sampled, for each pixel of a ``size`` x ``size`` output, at the source point ``matrix`` maps it
    to: uint8 [size, size, C]. Outside the frame the edge pixels repeat (``replicate``) or black comes in.

    The source points are rounded here, as OpenCV 4's WarpPerspectiveInvoker rounds them, into OpenCV's
    fixed-point map (integer pixel + a 1/32 fraction index); ``cv2.remap`` then weighs the four neighbours
    with its 15-bit table, which OpenCV 4 and 5 share (tests/runtime/person/test_landmarks.py holds it to a
    numpy oracle)."""
    v, u = np.mgrid[0:size, 0:size].astype(np.float64)
    wz = matrix[2, 0] * u + matrix[2, 1] * v + matrix[2, 2]
    wz = np.divide(INTER_TAB_SIZE, wz, out=np.zeros_like(wz), where=wz != 0)
    limit = float(np.iinfo(np.int32).max)
    x, y = [np.clip(np.rint((matrix[i, 0] * u + matrix[i, 1] * v + matrix[i, 2]) * wz), -limit, limit).astype(np.int32)
            for i in (0, 1)]  # [size, size] in 1/32 px, rounded half to even as cvRound
    whole = np.stack([x >> INTER_BITS, y >> INTER_BITS], axis=-1).clip(-32768, 32767).astype(np.int16)  # [size, size, 2]
    fraction = ((y & (INTER_TAB_SIZE - 1)) * INTER_TAB_SIZE + (x & (INTER_TAB_SIZE - 1))).astype(np.uint16)
    border = cv2.BORDER_REPLICATE if replicate else cv2.BORDER_CONSTANT
    return cv2.remap(image, whole, fraction, cv2.INTER_LINEAR, borderMode=border, borderValue=0)
