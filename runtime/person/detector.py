"""The pose detector (MediaPipe's BlazePose detector): SSD anchors, box decoding, weighted NMS, letterbox removal.

Each step follows the calculator of mediapipe/modules/pose_detection/pose_detection_cpu.pbtxt named in its
docstring; the constants are that graph's options. A detection is a box and 4 keypoints: 0 the hips' centre,
1 a point whose distance from it is the radius of a circle around the whole body (its direction gives the
body's rotation), 2 the shoulders' centre, 3 the same for the upper body.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from trioman.runtime.person.models import TfliteModel, check_image
from trioman.runtime.person.warp import crop_homography, warp_bilinear

INPUT_SIZE = 224  # ImageToTensorCalculator output_tensor_width/height
# SsdAnchorsCalculator options: strides 8, 16, 32, 32, 32 over a 224 input; layers of one stride share a grid.
STRIDES = (8, 16, 32, 32, 32)
ANCHORS_PER_LAYER = 2  # aspect_ratios: 1.0 plus the interpolated scale (interpolated_scale_aspect_ratio 1.0)
NUM_ANCHORS = 2254  # TensorsToDetectionsCalculator num_boxes: 28^2 * 2 + 14^2 * 2 + 7^2 * 6
NUM_KEYPOINTS = 4
SCALE = 224.0  # x_scale, y_scale, w_scale, h_scale
SCORE_CLIP = 100.0  # score_clipping_thresh
MIN_SCORE = 0.5  # min_score_thresh (mediapipe.solutions.pose's min_detection_confidence)
NMS_IOU = 0.3  # NonMaxSuppressionCalculator min_suppression_threshold, INTERSECTION_OVER_UNION, WEIGHTED


@dataclass(frozen=True)
class Detection:
    """One person found by the detector, in frame pixels (the frame spans [0, W] x [0, H])."""

    score: float  # sigmoid of the best anchor's logit, in (0, 1)
    box: np.ndarray  # [4] x0, y0, x1, y1
    keypoints: np.ndarray  # [4, 2] x, y: hips' centre, full-body radius point, shoulders' centre, upper-body point


def ssd_anchors() -> np.ndarray:
    """The detector's anchor centres, normalised to [0, 1]: [2254, 2] x, y (every anchor is 1 x 1,
    ``fixed_anchor_size``), grid by grid (28^2, 14^2, 7^2 cells), row-major, the anchors of a cell together.

    mediapipe/calculators/tflite/ssd_anchors_calculator.cc, GenerateAnchors: consecutive layers with one
    stride are merged into one grid; each layer adds ANCHORS_PER_LAYER anchors per cell at offset 0.5.
    """
    grids = []
    layer = 0
    while layer < len(STRIDES):
        same = 1
        while layer + same < len(STRIDES) and STRIDES[layer + same] == STRIDES[layer]:
            same += 1
        cells = int(np.ceil(INPUT_SIZE / STRIDES[layer]))
        yy, xx = np.meshgrid(np.arange(cells), np.arange(cells), indexing="ij")
        centres = np.stack([(xx + 0.5) / cells, (yy + 0.5) / cells], axis=-1).reshape(-1, 1, 2)  # [cells^2, 1, 2]
        grids.append(np.repeat(centres, same * ANCHORS_PER_LAYER, axis=1).reshape(-1, 2))
        layer += same
    return np.concatenate(grids).astype(np.float32)


ANCHORS = ssd_anchors()


def decode(raw_boxes: np.ndarray,  # [2254, 12] x, y, w, h, then 4 keypoints x, y; in 224-input pixels about the anchor
           raw_scores: np.ndarray,  # [2254] logits
           min_score: float = MIN_SCORE,
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The anchors whose score reaches ``min_score``: (scores [N], boxes [N, 4] x0, y0, x1, y1, keypoints
    [N, 4, 2] x, y), in the letterboxed input's normalised coordinates, the input's anchor order.

    TensorsToDetectionsCalculator (DecodeBoxes, XYWH since ``reverse_output_order``; the score clipped to
    +-100, then a sigmoid; boxes of negative or NaN size dropped, as ConvertToDetections does).
    """
    raw_boxes = np.asarray(raw_boxes, np.float32).reshape(NUM_ANCHORS, 4 + 2 * NUM_KEYPOINTS)
    raw_scores = np.asarray(raw_scores, np.float32).reshape(NUM_ANCHORS)
    scores = (1.0 / (1.0 + np.exp(-np.clip(raw_scores, -SCORE_CLIP, SCORE_CLIP).astype(np.float64)))).astype(np.float32)
    centre = raw_boxes[:, 0:2] / SCALE + ANCHORS  # anchor w = h = 1
    size = raw_boxes[:, 2:4] / SCALE
    boxes = np.concatenate([centre - size / 2, centre + size / 2], axis=1)  # [2254, 4]
    keypoints = raw_boxes[:, 4:].reshape(NUM_ANCHORS, NUM_KEYPOINTS, 2) / SCALE + ANCHORS[:, None, :]
    keep = (scores >= min_score) & (size >= 0).all(axis=1)  # a NaN size compares False
    return scores[keep], boxes[keep], keypoints[keep]


def iou(box: np.ndarray,  # [4] x0, y0, x1, y1
        boxes: np.ndarray,  # [N, 4]
        ) -> np.ndarray:
    """Intersection over union of ``box`` with each of ``boxes``: [N] (0 where they do not meet)."""
    w = np.clip(np.minimum(box[2], boxes[:, 2]) - np.maximum(box[0], boxes[:, 0]), 0, None)
    h = np.clip(np.minimum(box[3], boxes[:, 3]) - np.maximum(box[1], boxes[:, 1]), 0, None)
    inter = w * h
    union = (box[2] - box[0]) * (box[3] - box[1]) + (boxes[:, 2] - boxes[:, 0]) * (boxes[:, 3] - boxes[:, 1]) - inter
    return np.where(union > 0, inter / np.where(union > 0, union, 1), 0.0)


def weighted_nms(scores: np.ndarray,  # [N]
                 boxes: np.ndarray,  # [N, 4]
                 keypoints: np.ndarray,  # [N, K, 2]
                 threshold: float = NMS_IOU,
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Weighted non-maximum suppression: (scores [M], boxes [M, 4], keypoints [M, K, 2]), best first.

    mediapipe/calculators/util/non_max_suppression_calculator.cc, WeightedNonMaxSuppression: the best
    remaining detection takes every remaining one whose IoU with it exceeds ``threshold`` (itself included)
    and becomes their score-weighted mean box and keypoints, keeping its own score.
    """
    order = np.argsort(-scores, kind="stable")
    out_scores, out_boxes, out_keypoints = [], [], []
    while order.size:
        top = order[0]
        close = iou(boxes[top], boxes[order]) > threshold
        close[0] = True  # the top box itself (also when its area is 0)
        group, order = order[close], order[~close]
        w = scores[group][:, None]  # [G, 1]
        out_scores.append(scores[top])
        out_boxes.append((boxes[group] * w).sum(0) / w.sum())
        out_keypoints.append((keypoints[group] * w[:, :, None]).sum(0) / w.sum())
    k = keypoints.shape[1]
    return (np.array(out_scores, np.float32), np.array(out_boxes, np.float32).reshape(-1, 4),
            np.array(out_keypoints, np.float32).reshape(-1, k, 2))


def detector_input(image: np.ndarray) -> np.ndarray:
    """The detector's input: ``image`` (uint8 [H, W, 3]) padded to a square with black, resized to 224 with
    bilinear interpolation (``warp_bilinear``), scaled to [-1, 1]: [1, 224, 224, 3] float32 (BORDER_ZERO, range -1..1)."""
    h, w = image.shape[:2]
    side = max(h, w)  # the frame padded to a centred square (keep_aspect_ratio)
    square = warp_bilinear(image, crop_homography((w / 2, h / 2), side, 0.0, INPUT_SIZE), INPUT_SIZE, replicate=False)
    return (square.astype(np.float32) * np.float32(2.0 / 255.0) - np.float32(1.0))[None]


def detect(model: TfliteModel, image: np.ndarray, min_score: float = MIN_SCORE) -> list[Detection]:
    """Every person the detector finds in ``image`` (uint8 RGB [H, W, 3]) with a score >= ``min_score``,
    best first, in frame pixels (DetectionLetterboxRemovalCalculator, then times W and H)."""
    image = check_image(image)
    h, w = image.shape[:2]
    out = model(detector_input(image))
    scores, boxes, keypoints = weighted_nms(*decode(out["Identity"][0], out["Identity_1"][0, :, 0], min_score))
    # Normalised letterboxed coordinates -> frame pixels: x_px = (x - pad_x) / (1 - 2 pad_x) * W = x * side - (side - W) / 2
    side = max(h, w)
    offset = np.array([(side - w) / 2, (side - h) / 2], np.float32)
    boxes = boxes * side - np.tile(offset, 2)
    keypoints = keypoints * side - offset
    return [Detection(float(s), b.astype(np.float64), k.astype(np.float64)) for s, b, k in zip(scores, boxes, keypoints)]
