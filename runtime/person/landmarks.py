"""The pose landmark model (BlazePose full) on a rotated crop: the region of interest, the crop, the 33 keypoints,
the world landmarks and the person mask back in the frame.

Each step follows mediapipe/modules/pose_landmark/pose_landmark_by_roi_cpu.pbtxt and the graphs it uses
(tensors_to_pose_landmarks_and_segmentation.pbtxt, pose_landmarks_and_segmentation_inverse_projection.pbtxt);
the region of interest follows pose_detection_to_roi.pbtxt and pose_landmarks_to_roi.pbtxt. Warps use
OpenCV's pixel coordinates as MediaPipe's do; keypoints are MediaPipe's normalised coordinates times the
frame size, so the frame spans [0, W] x [0, H].
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from trioman.runtime.person.models import TfliteModel, check_image
from trioman.runtime.person.warp import crop_homography, warp_bilinear

INPUT_SIZE = 256  # ImageToTensorCalculator output size (pose_landmark_by_roi_cpu.pbtxt)
NUM_LANDMARKS = 39  # TensorsToLandmarksCalculator num_landmarks: 33 keypoints, 2 for the next crop, 4 unused
NUM_KEYPOINTS = 33
AUX = slice(33, 35)  # the two points that give the next frame's crop (SplitNormalizedLandmarkListCalculator 33..35)
ROI_SCALE = 1.25  # RectTransformationCalculator scale_x, scale_y (square_long) in both *_to_roi graphs
ROI_TARGET_ANGLE = math.pi / 2  # rotation_vector_target_angle_degrees: 90
HEATMAP_KERNEL = 7  # RefineLandmarksFromHeatmapCalculator kernel_size
HEATMAP_MIN_CONFIDENCE = 0.5  # its min_confidence_to_refine (the default)
MIN_PERSON_SCORE = 0.5  # ThresholdingCalculator threshold (mediapipe.solutions.pose's min_tracking_confidence)

# The 33 keypoints in the model's order (MediaPipe Pose's PoseLandmark).
KEYPOINT_NAMES = (
    "nose", "left_eye_inner", "left_eye", "left_eye_outer", "right_eye_inner", "right_eye", "right_eye_outer",
    "left_ear", "right_ear", "mouth_left", "mouth_right", "left_shoulder", "right_shoulder", "left_elbow",
    "right_elbow", "left_wrist", "right_wrist", "left_pinky", "right_pinky", "left_index", "right_index",
    "left_thumb", "right_thumb", "left_hip", "right_hip", "left_knee", "right_knee", "left_ankle", "right_ankle",
    "left_heel", "right_heel", "left_foot_index", "right_foot_index",
)


@dataclass(frozen=True)
class Roi:
    """A square crop of the frame: its centre and side in frame pixels, its rotation in radians (the crop's
    x axis turned by ``rotation`` from the frame's, clockwise on screen: image y points down)."""

    center: tuple[float, float]
    size: float
    rotation: float


def normalize_radians(angle: float) -> float:
    """``angle`` in [-pi, pi) (mediapipe/calculators/util/detections_to_rects_calculator.cc, NormalizeRadians)."""
    return angle - 2 * math.pi * math.floor((angle + math.pi) / (2 * math.pi))


def roi_from_points(center: np.ndarray,  # [2] px: the hips' centre
                    scale: np.ndarray,  # [2] px: the full-body radius point
                    ) -> Roi:
    """The crop for the landmark model from two points: centred on ``center``, side 2 |scale - center| x 1.25,
    turned so that ``scale`` lies straight up (AlignmentPointsRectsCalculator + RectTransformationCalculator,
    as the detector's keypoints 0, 1 and the landmark model's points 33, 34 both use them)."""
    x0, y0 = (float(v) for v in center)
    x1, y1 = (float(v) for v in scale)
    size = 2.0 * math.hypot(x1 - x0, y1 - y0) * ROI_SCALE
    return Roi((x0, y0), size, normalize_radians(ROI_TARGET_ANGLE - math.atan2(-(y1 - y0), x1 - x0)))


def crop_matrix(roi: Roi, size: int = INPUT_SIZE) -> np.ndarray:
    """[2, 3] affine map from crop coordinates (``size`` x ``size``) to frame pixels: crop point (u, v) is the
    frame point ``center + R(rotation) ((u / size - 0.5) side, (v / size - 0.5) side)``. With ``size`` 1 it
    un-projects normalised landmarks (LandmarkProjectionCalculator); with 256 it carries the mask back
    (WarpAffineCalculator); the input crop itself is ``warp.crop_homography``, the same map built as
    MediaPipe builds it."""
    c, s = math.cos(roi.rotation), math.sin(roi.rotation)
    r = np.array([[c, -s], [s, c]])
    a = r * (roi.size / size)
    b = np.asarray(roi.center) - r @ np.array([roi.size / 2, roi.size / 2])
    return np.concatenate([a, b[:, None]], axis=1)


def crop(image: np.ndarray, roi: Roi) -> np.ndarray:
    """The landmark model's input: the ``roi`` of ``image`` (uint8 [H, W, 3]), bilinear, edges replicated,
    scaled to [0, 1]: [1, 256, 256, 3] float32."""
    patch = warp_bilinear(image, crop_homography(roi.center, roi.size, roi.rotation, INPUT_SIZE), INPUT_SIZE,
                          replicate=True)
    return (patch.astype(np.float32) * np.float32(1.0 / 255.0))[None]


def sigmoid(x: np.ndarray) -> np.ndarray:
    """The logistic function in float64, without overflow warnings for large logits."""
    x = np.asarray(x, np.float64)
    return np.exp(-np.logaddexp(0.0, -x))


def refine_from_heatmap(points: np.ndarray,  # [L, 2] x, y normalised to the crop
                        heatmap: np.ndarray,  # [h, w, L] logits
                        ) -> np.ndarray:
    """``points`` moved to the sigmoid-weighted mean of the heatmap in a 7 x 7 window around each, where the
    window's peak reaches 0.5: [L, 2] (mediapipe/calculators/util/refine_landmarks_from_heatmap_calculator.cc;
    the window's cell index, not its centre, is the coordinate, and a point off the heatmap stays)."""
    h, w, n = heatmap.shape
    out = points.copy()
    half = (HEATMAP_KERNEL - 1) // 2
    cols = np.trunc(points[:, 0] * w).astype(np.int64)  # C++'s float -> int conversion
    rows = np.trunc(points[:, 1] * h).astype(np.int64)
    for i in range(n):
        col, row = cols[i], rows[i]
        if not (0 <= col < w and 0 <= row < h):
            continue
        r0, r1, c0, c1 = max(0, row - half), min(h, row + half + 1), max(0, col - half), min(w, col + half + 1)
        conf = sigmoid(heatmap[r0:r1, c0:c1, i].astype(np.float64))  # [rows, cols]
        total = conf.sum()
        if conf.max() >= HEATMAP_MIN_CONFIDENCE and total > 0:
            out[i, 0] = (conf.sum(0) @ np.arange(c0, c1)) / w / total
            out[i, 1] = (conf.sum(1) @ np.arange(r0, r1)) / h / total
    return out


@dataclass(frozen=True)
class Landmarks:
    """The landmark model's answer for one crop, in frame pixels."""

    score: float  # the model's person flag in [0, 1]; below MIN_PERSON_SCORE MediaPipe drops the frame
    keypoints: np.ndarray  # [33, 2] x, y px
    visibility: np.ndarray  # [33] in [0, 1]: in the frame and not occluded
    presence: np.ndarray  # [33] in [0, 1]: in the frame
    world: np.ndarray  # [33, 3] m: origin at the hips' centre, axes of the camera (x right, y down, z forward)
    mask: np.ndarray  # [H, W] float32 in [0, 1], 0 outside the crop
    next_roi: Roi  # the crop for the next frame (points 33, 34)


def estimate(model: TfliteModel, image: np.ndarray, roi: Roi) -> Landmarks:
    """The landmark model on the ``roi`` crop of ``image`` (uint8 RGB [H, W, 3]), its outputs mapped back to
    the frame (TensorsToPoseLandmarksAndSegmentation, then the inverse projection)."""
    image = check_image(image)
    if not (math.isfinite(roi.size) and roi.size > 0 and all(math.isfinite(v) for v in (*roi.center, roi.rotation))):
        raise ValueError(f"roi: expected a finite centre and rotation and a side > 0, got {roi}")
    h, w = image.shape[:2]
    out = model(crop(image, roi))
    raw = out["Identity"].reshape(NUM_LANDMARKS, 5).astype(np.float64)
    points = refine_from_heatmap(raw[:, :2] / INPUT_SIZE, out["Identity_3"][0])  # [39, 2] normalised to the crop
    m = crop_matrix(roi, size=1)  # normalised crop -> frame px (LandmarkProjectionCalculator)
    frame_points = points @ m[:, :2].T + m[:, 2]  # [39, 2]
    c, s = math.cos(roi.rotation), math.sin(roi.rotation)
    world = out["Identity_4"].reshape(NUM_LANDMARKS, 3)[:NUM_KEYPOINTS].astype(np.float64)  # [33, 3]
    world = np.stack([c * world[:, 0] - s * world[:, 1], s * world[:, 0] + c * world[:, 1], world[:, 2]], axis=1)
    # Mask: sigmoid on the crop (TensorsToSegmentationCalculator), warped into the frame, zero outside
    # (WarpAffineCalculator with the crop's inverse matrix, BORDER_ZERO).
    mask = cv2.warpAffine(sigmoid(out["Identity_2"][0, :, :, 0]).astype(np.float32), crop_matrix(roi), (w, h),
                          flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    return Landmarks(
        score=float(out["Identity_1"].reshape(())),
        keypoints=frame_points[:NUM_KEYPOINTS],
        visibility=sigmoid(raw[:NUM_KEYPOINTS, 3]),
        presence=sigmoid(raw[:NUM_KEYPOINTS, 4]),
        world=world,
        mask=np.clip(mask, 0.0, 1.0),
        next_roi=roi_from_points(frame_points[AUX][0], frame_points[AUX][1]),
    )
