"""The pose detector's post-processing on synthetic tensors: the SSD anchors of pose_detection_cpu.pbtxt, box
and keypoint decoding, the score threshold, weighted NMS, and the letterbox in both directions."""

import re

import numpy as np
import pytest

from trioman.runtime.person import detector
from trioman.runtime.person.detector import ANCHORS, NUM_ANCHORS, decode, detect, detector_input, iou, ssd_anchors, weighted_nms


def test_anchors_count_and_grid_layout():
    anchors = ssd_anchors()
    assert anchors.shape == (NUM_ANCHORS, 2) == (2254, 2)
    # 28 x 28 cells (stride 8) with 2 anchors each, then 14 x 14 (stride 16) with 2, then 7 x 7 (three
    # stride-32 layers merged) with 6; row-major, the anchors of one cell together, centres at (i + 0.5) / n.
    start = 0
    for cells, per_cell in ((28, 2), (14, 2), (7, 6)):
        grid = anchors[start:start + cells * cells * per_cell].reshape(cells, cells, per_cell, 2)
        centres = (np.arange(cells) + 0.5) / cells
        np.testing.assert_allclose(grid[..., 0], np.broadcast_to(centres[None, :, None], grid.shape[:3]), atol=1e-7)
        np.testing.assert_allclose(grid[..., 1], np.broadcast_to(centres[:, None, None], grid.shape[:3]), atol=1e-7)
        start += cells * cells * per_cell
    assert start == NUM_ANCHORS
    np.testing.assert_array_equal(ANCHORS, anchors)


def raw_tensors(entries: dict[int, tuple[float, tuple[float, float, float, float]]]) -> tuple[np.ndarray, np.ndarray]:
    """Model outputs with the given anchors at logit ``s`` and box (dx, dy, w, h) in input pixels, keypoint k
    at the box centre + (k, -k) px; every other anchor at logit -10."""
    boxes = np.zeros((NUM_ANCHORS, 12), np.float32)
    scores = np.full(NUM_ANCHORS, -10.0, np.float32)
    for i, (logit, box) in entries.items():
        scores[i] = logit
        boxes[i, :4] = box
        boxes[i, 4:] = np.array([[box[0] + k, box[1] - k] for k in range(4)]).ravel()
    return boxes, scores


def test_decode_boxes_keypoints_and_threshold():
    i = 28 * 28 * 2 + 14 * 14 * 2 + (3 * 7 + 4) * 6 + 5  # the last anchor of cell (row 3, col 4) of the 7 x 7 grid
    boxes, scores = raw_tensors({i: (2.0, (22.4, -11.2, 44.8, 89.6)), 0: (0.0, (0, 0, 10, 10)), 1: (-0.1, (0, 0, 10, 10))})
    s, b, k = decode(boxes, scores)
    assert len(s) == 2  # logit 0 -> 0.5 reaches min_score 0.5; -0.1 does not
    np.testing.assert_allclose(s, [0.5, 1 / (1 + np.exp(-2.0))], rtol=1e-6)
    cx, cy = (4.5 / 7 + 0.1, 3.5 / 7 - 0.05)  # anchor centre + offset / 224
    np.testing.assert_allclose(b[1], [cx - 0.1, cy - 0.2, cx + 0.1, cy + 0.2], atol=1e-6)
    np.testing.assert_allclose(k[1], [[cx + j / 224, cy - j / 224] for j in range(4)], atol=1e-6)
    # A box of negative or NaN size is dropped (ConvertToDetections); huge logits are clipped, not inf.
    boxes, scores = raw_tensors({5: (1e9, (0, 0, -1, 4)), 6: (3.0, (0, 0, np.nan, 4)), 7: (1e9, (0, 0, 4, 4))})
    s, b, k = decode(boxes, scores)
    assert len(s) == 1 and s[0] == np.float32(1.0)


def test_weighted_nms_merges_overlaps_and_keeps_the_top_score():
    scores = np.array([0.6, 0.9, 0.8], np.float32)
    boxes = np.array([[0.5, 0.5, 0.7, 0.7], [0.1, 0.1, 0.3, 0.3], [0.11, 0.1, 0.31, 0.3]], np.float32)
    keypoints = boxes[:, None, :2].repeat(4, axis=1)
    s, b, k = weighted_nms(scores, boxes, keypoints)
    np.testing.assert_allclose(s, [0.9, 0.6])
    merged = (0.9 * boxes[1] + 0.8 * boxes[2]) / 1.7  # the score-weighted mean of the overlapping pair
    np.testing.assert_allclose(b[0], merged, rtol=1e-6)
    np.testing.assert_allclose(k[0], np.repeat(merged[None, :2], 4, axis=0), rtol=1e-6)
    np.testing.assert_allclose(b[1], boxes[0])
    # IoU exactly at the threshold does not merge (MediaPipe keeps "similarity > threshold").
    assert iou(np.array([0, 0, 1, 1.0]), np.array([[0, 0, 1, 0.3]]))[0] == pytest.approx(0.3)
    s, _, _ = weighted_nms(np.array([0.9, 0.8]), np.array([[0, 0, 1, 1.0], [2, 2, 3, 3]]), np.zeros((2, 4, 2)))
    assert len(s) == 2
    s, b, k = weighted_nms(np.zeros(0, np.float32), np.zeros((0, 4), np.float32), np.zeros((0, 4, 2), np.float32))
    assert s.shape == (0,) and b.shape == (0, 4) and k.shape == (0, 4, 2)


class FakeModel:
    """A detector whose outputs are fixed tensors (the model itself is tested by the parity test)."""

    def __init__(self, boxes, scores):
        self.out = {"Identity": boxes[None], "Identity_1": scores[None, :, None]}
        self.inputs = []

    def __call__(self, x):
        self.inputs.append(x)
        return self.out


def test_detect_removes_the_letterbox():
    # A portrait frame 100 x 200 (W x H) pads to 200 x 200: a normalised x maps to x * 200 - 50 px.
    i = 28 * 28 * 2 + 14 * 14 * 2 + (3 * 7 + 3) * 6  # the centre cell of the 7 x 7 grid: anchor (0.5, 0.5)
    model = FakeModel(*raw_tensors({i: (5.0, (0, 0, 22.4, 44.8))}))
    image = np.zeros((200, 100, 3), np.uint8)
    (d,) = detect(model, image)
    np.testing.assert_allclose(d.box, [40, 80, 60, 120], atol=1e-4)
    np.testing.assert_allclose(d.keypoints[1], [50 + 200 / 224, 100 - 200 / 224], atol=1e-4)
    x = model.inputs[0]
    assert x.shape == (1, 224, 224, 3) and x.dtype == np.float32
    # Black padding -> -1 on both sides; the frame itself (0 here) is -1 too, a white frame +1.
    white = detector_input(np.full((200, 100, 3), 255, np.uint8))[0]
    assert white[112, 112].tolist() == [1, 1, 1] and white[112, 5].tolist() == [-1, -1, -1]
    assert white[112, 218].tolist() == [-1, -1, -1]


def test_detect_rejects_bad_images():
    model = FakeModel(*raw_tensors({}))
    for bad, shown in ((np.zeros((4, 4, 3), np.float32), "float32 [4, 4, 3]"), (np.zeros((4, 4), np.uint8), "uint8 [4, 4]"),
                       (np.zeros((4, 4, 4), np.uint8), "uint8 [4, 4, 4]"), (np.zeros((1, 4, 3), np.uint8), "uint8 [1, 4, 3]")):
        with pytest.raises(ValueError, match="^" + re.escape(f"image: expected uint8 [H, W, 3] with H, W >= 2, got {shown}") + "$"):
            detect(model, bad)
    with pytest.raises(ValueError, match=r"^image: expected a numpy uint8 array \[H, W, 3\], got list$"):
        detect(model, [[0]])
    assert detector.MIN_SCORE == 0.5 and detector.NMS_IOU == 0.3  # pose_detection_cpu.pbtxt
