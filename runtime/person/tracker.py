"""The person in each frame of a video: detector when tracking is lost, landmark model on the crop that the
previous frame's points 33, 34 give (mediapipe/modules/pose_landmark/pose_landmark_cpu.pbtxt), and a verdict
per frame: kept ("ok"), or dropped with the reason (no person, two people, cut by the frame's edge, low
confidence).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Iterable, Iterator

import numpy as np

from trioman.runtime.person import detector, landmarks
from trioman.runtime.person.landmarks import KEYPOINT_NAMES, Landmarks, Roi, estimate, roi_from_points
from trioman.runtime.person.models import PoseModels, check_image, load_models

STATUSES = ("ok", "no_person", "two_people", "cut_by_edge", "low_confidence")  # in the order they are decided
TORSO = (11, 12, 23, 24)  # shoulders and hips


@dataclass(frozen=True)
class TrackerConfig:
    """Thresholds of ``PersonTracker``; scores and visibilities in [0, 1], margins in pixels."""

    min_detection_score: float = detector.MIN_SCORE  # a detection counts from this score (MediaPipe's 0.5)
    min_tracking_score: float = landmarks.MIN_PERSON_SCORE  # below: the person is lost, detect again (MediaPipe's 0.5)
    second_person_score: float = 0.5  # a second detection at or above this -> "two_people"
    min_person_score: float = 0.8  # the landmark model's person flag below this -> "low_confidence"
    min_torso_visibility: float = 0.5  # the mean visibility of shoulders and hips below this -> "low_confidence"
    edge_margin: float = 0.0  # a keypoint further than this outside the frame -> "cut_by_edge"
    edge_mask_fraction: float = 0.01  # person pixels (mask >= 0.5) on more than this share of a frame side -> "cut_by_edge"
    redetect_every: int = 30  # also run the detector every N tracked frames, to see a second person (0: never)
    threads: int = 1  # LiteRT threads per model

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name in ("redetect_every", "threads"):
                low = 1 if f.name == "threads" else 0
                if not isinstance(value, int) or isinstance(value, bool) or value < low:
                    raise ValueError(f"{f.name}: must be an integer >= {low}, got {value!r}")
                continue
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ValueError(f"{f.name}: must be a finite number, got {value!r}")
            if f.name == "edge_margin" and value < 0:
                raise ValueError(f"edge_margin: must be >= 0 pixels, got {value!r}")
            if f.name != "edge_margin" and not 0 <= value <= 1:
                raise ValueError(f"{f.name}: must lie in [0, 1], got {value!r}")


@dataclass(frozen=True)
class PersonFrame:
    """The person in one frame (frame pixels, the frame spanning [0, W] x [0, H]); the arrays are None when
    no person was found."""

    status: str  # one of STATUSES: "ok", or why the frame should be dropped
    reason: str  # "" when ok; else what was seen, with the numbers
    score: float  # the landmark model's person flag in [0, 1] (0 without a person)
    box: np.ndarray | None  # [4] x0, y0, x1, y1: the mask's pixels >= 0.5 (the keypoints' box when it has none)
    keypoints: np.ndarray | None  # [33, 2] x, y in KEYPOINT_NAMES order
    confidence: np.ndarray | None  # [33] visibility in [0, 1]: in the frame and not occluded
    presence: np.ndarray | None  # [33] in [0, 1]: in the frame
    world: np.ndarray | None  # [33, 3] metres, origin at the hips' centre, camera axes (x right, y down, z forward)
    mask: np.ndarray  # [H, W] float32 in [0, 1], 1 = person
    people: int | None  # detections >= second_person_score, when the detector ran on this frame; else None
    detected: bool  # whether the detector ran on this frame

    @property
    def ok(self) -> bool:
        return self.status == "ok"


class PersonTracker:
    """Per-frame person model over a video (uint8 RGB frames [H, W, 3], one size).

    The detector runs on the first frame, whenever the landmark model's person flag drops below
    ``min_tracking_score`` (then the same frame is estimated again on the new crop), on a frame of
    another size, and every ``redetect_every`` tracked frames (only to count people: the crop stays the
    tracked one). ``detector_runs`` counts its calls.
    """

    def __init__(self, config: TrackerConfig | None = None, models: PoseModels | None = None,
                 model_root: Path | None = None) -> None:
        self.config = config if config is not None else TrackerConfig()
        self.models = models if models is not None else load_models(model_root, self.config.threads)
        self.detector_runs = 0
        self._roi: Roi | None = None
        self._size: tuple[int, int] | None = None
        self._since_detect = 0

    def reset(self) -> None:
        """Forget the tracked person: the next frame runs the detector."""
        self._roi = None

    def _detect(self, image: np.ndarray) -> list[detector.Detection]:
        self.detector_runs += 1
        self._since_detect = 0
        return detector.detect(self.models.detector, image, self.config.min_detection_score)

    def __call__(self, image: np.ndarray) -> PersonFrame:
        """The person in ``image`` (uint8 RGB [H, W, 3]); the next call continues the track."""
        image = check_image(image)
        cfg = self.config
        if image.shape[:2] != self._size:
            self._size, self._roi = image.shape[:2], None
        tracked, detections = self._roi, None
        if tracked is None or (cfg.redetect_every and self._since_detect >= cfg.redetect_every):
            detections = self._detect(image)
        else:
            self._since_detect += 1
        result = estimate(self.models.landmarks, image, tracked) if tracked is not None else None
        if result is None or result.score < cfg.min_tracking_score:  # no track, or lost: the detector's crop
            if detections is None:
                detections = self._detect(image)
            result = None
            if detections:
                result = estimate(self.models.landmarks, image, roi_from_points(*detections[0].keypoints[:2]))
        if result is None or result.score < cfg.min_tracking_score:
            self._roi = None
            return self._no_person(image, result, detections)
        self._roi = result.next_roi
        return self._verdict(image, result, detections)

    def track(self, frames: Iterable[np.ndarray]) -> Iterator[PersonFrame]:
        """``self(frame)`` for each of ``frames``, in order, from a fresh track."""
        self.reset()
        for frame in frames:
            yield self(frame)

    def _people(self, detections: list[detector.Detection] | None) -> int | None:
        if detections is None:
            return None
        return sum(d.score >= self.config.second_person_score for d in detections)

    def _no_person(self, image: np.ndarray, result: Landmarks | None,
                   detections: list[detector.Detection] | None) -> PersonFrame:
        if not detections:
            reason = f"the detector found no person (score >= {self.config.min_detection_score:g})"
        else:
            reason = (f"the landmark model's person flag {result.score if result else 0.0:.2f} < "
                      f"{self.config.min_tracking_score:g} on the detector's crop")
        return PersonFrame("no_person", reason, result.score if result else 0.0, None, None, None, None, None,
                           np.zeros(image.shape[:2], np.float32), self._people(detections), True)

    def _verdict(self, image: np.ndarray, lm: Landmarks, detections: list[detector.Detection] | None) -> PersonFrame:
        cfg = self.config
        h, w = image.shape[:2]
        people = self._people(detections)
        person = lm.mask >= 0.5  # [H, W]
        if person.any():
            rows, cols = np.flatnonzero(person.any(1)), np.flatnonzero(person.any(0))
            box = np.array([cols[0], rows[0], cols[-1] + 1, rows[-1] + 1], np.float64)
        else:
            box = np.concatenate([lm.keypoints.min(0), lm.keypoints.max(0)])
        outside = ((lm.keypoints < -cfg.edge_margin) | (lm.keypoints > np.array([w, h]) + cfg.edge_margin)).any(1)
        sides = {"top": person[0].mean(), "bottom": person[-1].mean(), "left": person[:, 0].mean(),
                 "right": person[:, -1].mean()}
        touched = [f"{k} {v:.0%}" for k, v in sides.items() if v > cfg.edge_mask_fraction]
        torso = float(lm.visibility[list(TORSO)].mean())
        if people is not None and people > 1:
            status = "two_people"
            scores = ", ".join(f"{d.score:.2f}" for d in detections if d.score >= cfg.second_person_score)
            reason = f"the detector found {people} people (scores {scores})"
        elif outside.any() or touched:
            status = "cut_by_edge"
            names = [KEYPOINT_NAMES[i] for i in np.flatnonzero(outside)]
            reason = "; ".join(part for part in (
                f"keypoints outside the frame: {', '.join(names)}" if names else "",
                f"the mask reaches the frame's edge: {', '.join(touched)} of the side" if touched else "") if part)
        elif lm.score < cfg.min_person_score or torso < cfg.min_torso_visibility:
            status = "low_confidence"
            reason = (f"person flag {lm.score:.2f} (min {cfg.min_person_score:g}), torso visibility {torso:.2f} "
                      f"(min {cfg.min_torso_visibility:g})")
        else:
            status, reason = "ok", ""
        return PersonFrame(status, reason, lm.score, box, lm.keypoints, lm.visibility, lm.presence, lm.world,
                           lm.mask.astype(np.float32), people, detections is not None)
