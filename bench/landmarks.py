"""``trioman bench landmarks``: where MediaPipe's pose landmarks sit on the Anny body, measured on realistic
synthetic subjects whose true poses and cameras are known. For each landmark: the RMS distance (in person heights)
of its point on Anny (``toolkit/fit/keypoints.py``, with the offsets it uses now) projected by the true pose and
camera to MediaPipe's keypoint; and, for the joint landmarks, the rest-frame offset from the joint, moved with it,
that brings the projections closest (least squares, Gauss-Newton), scored on subjects it was not fitted on (the
subjects split in two halves, each fitted on one and scored on the other). The report prints the table
``keypoints.JOINT_OFFSETS`` takes, fitted on every subject.

Frames a landmark is counted on: MediaPipe's confidence >= ``MIN_CONFIDENCE`` and its keypoint within ``CUT``
person heights of the joint's projection (the rest are readings of the wrong side or of a hidden limb, which the
fit meets with its mirrored-frame search and its robust loss, not with an offset)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from trioman.bench.common import machine
from trioman.bench.config import LandmarksBenchConfig

CUT = 0.08  # person heights
MIN_CONFIDENCE = 0.5


@dataclass
class _Frames:
    """One subject's kept frames, for the joint landmarks: MediaPipe against the truth. M joint landmarks."""

    residual: list[np.ndarray]  # [M, 2] px: MediaPipe's keypoint minus the joint's true projection
    jacobian: list[np.ndarray]  # [M, 2, 3] px per m: the projection's change with a rest-frame offset
    confidence: list[np.ndarray]  # [M]
    height: list[float]  # the person's height in the frame, px
    now: list[np.ndarray]  # [27] px: the distance of every landmark's point (current offsets) to MediaPipe's keypoint
    now_confidence: list[np.ndarray]  # [27]


def _subject_frames(config: LandmarksBenchConfig, seed: int, tracker) -> _Frames:
    from trioman.runtime.cameras import project
    from trioman.runtime.formats import load_subject
    from trioman.toolkit.fit.keypoints import correspondence
    from trioman.toolkit.synth.subject import SynthConfig, TruthRenderer, synthesize_subject

    folder = Path(config.out) / "landmarks_work" / f"s{seed}"
    if not (folder / "subject.json").is_file():
        synthesize_subject(SynthConfig(seed=seed, size=config.size, frames=config.frames, aspect=9 / 16, style="realistic"),
                           folder, overwrite=True, progress=False)
    s = load_subject(folder)
    truth, body = TruthRenderer(s), s.body
    sk = body.skeleton
    corr = correspondence(body)
    joint = corr.joint >= 0
    rest = np.linalg.inv(sk.forward_kinematics(np.zeros((sk.num_joints, 3)), np.zeros(3)))
    out = _Frames([], [], [], [], [], [])
    previous = None
    for i in range(s.num_frames):
        if s.sequence[i] != previous:
            tracker.reset()
            previous = s.sequence[i]
        frame, _, mask = truth.recorded(i)
        p = tracker(np.rint(np.clip(frame, 0, 1) * 255).astype(np.uint8))
        if not p.ok:
            continue
        pose, trans = s.poses_true[i].astype(np.float64), s.trans[i].astype(np.float64)
        V, K = s.viewmat[i].astype(np.float64), s.K[i].astype(np.float64)
        G = sk.forward_kinematics(pose, trans)
        j = corr.joint[joint]
        cam = G[j, :3, 3] @ V[:3, :3].T + V[:3, 3]  # [M, 3]
        x, y, z = cam.T
        d_cam = np.zeros((len(j), 2, 3))  # d pixel / d camera point of a pinhole
        d_cam[:, 0, 0], d_cam[:, 0, 2] = K[0, 0] / z, -K[0, 0] * x / z ** 2
        d_cam[:, 1, 1], d_cam[:, 1, 2] = K[1, 1] / z, -K[1, 1] * y / z ** 2
        R = (G[j] @ rest[j])[:, :3, :3]  # the joints' skinning rotations
        uv, _ = project(G[j, :3, 3], V, K)
        rows = np.flatnonzero(mask.max(axis=1) >= 0.5)
        out.residual.append(p.keypoints[corr.landmarks[joint]] - uv)
        out.jacobian.append(d_cam @ V[:3, :3] @ R)
        out.confidence.append(p.confidence[corr.landmarks[joint]])
        out.height.append(float(rows[-1] - rows[0] + 1) if len(rows) > 1 else float(s.height))
        now, _ = project(corr.points(body, pose, trans), V, K)
        out.now.append(np.linalg.norm(p.keypoints[corr.landmarks] - now, axis=1))
        out.now_confidence.append(p.confidence[corr.landmarks])
    return out


def _inliers(f: _Frames, m: int) -> list[int]:
    return [k for k in range(len(f.height)) if f.confidence[k][m] >= MIN_CONFIDENCE
            and np.linalg.norm(f.residual[k][m]) <= CUT * f.height[k]]


def fit_offset(frames: list[_Frames], m: int) -> np.ndarray:
    """The rest-frame offset [3] (m) of joint landmark ``m`` that minimises its squared reprojection distance in
    person heights over the inlier frames (linearised at the joint: the offsets are centimetres)."""
    AtA, Atb = 1e-9 * np.eye(3), np.zeros(3)
    for f in frames:
        for k in _inliers(f, m):
            A, w = f.jacobian[k][m], 1.0 / f.height[k] ** 2
            AtA += w * A.T @ A
            Atb += w * A.T @ f.residual[k][m]
    return np.linalg.solve(AtA, Atb)


def offset_rms(frames: list[_Frames], m: int, offset: np.ndarray) -> float:
    """RMS distance in person heights over the inlier frames with ``offset`` applied (the linearised projection)."""
    err = [np.linalg.norm(f.residual[k][m] - f.jacobian[k][m] @ offset) / f.height[k] for f in frames for k in _inliers(f, m)]
    return float(np.sqrt(np.mean(np.square(err)))) if err else float("nan")


def bench_landmarks(config: LandmarksBenchConfig) -> dict:
    from trioman.runtime.person import PersonTracker
    from trioman.runtime.person.landmarks import KEYPOINT_NAMES
    from trioman.toolkit.fit.keypoints import JOINT_LANDMARKS, JOINT_OFFSETS, VERTEX_LANDMARKS

    tracker = PersonTracker()
    subjects = [_subject_frames(config, config.seed + k, tracker) for k in range(config.subjects)]
    if not any(f.height for f in subjects):
        raise ValueError("landmarks: the person model kept no frame of the calibration subjects")
    halves = (subjects[::2], subjects[1::2]) if len(subjects) > 1 else ()
    marks = sorted(set(JOINT_LANDMARKS) | set(VERTEX_LANDMARKS))  # correspondence()'s order
    joint_marks = sorted(JOINT_LANDMARKS)
    rows = []
    for i, mark in enumerate(marks):
        now = np.array([f.now[k][i] / f.height[k] for f in subjects for k in range(len(f.height))
                        if f.now_confidence[k][i] >= MIN_CONFIDENCE])
        row = {"landmark": mark, "name": KEYPOINT_NAMES[mark], "point": JOINT_LANDMARKS.get(mark, "vertex"),
               "offset_now_mm": [round(1000 * v, 1) for v in JOINT_OFFSETS.get(mark, (0.0, 0.0, 0.0))],
               "now_rms": round(float(np.sqrt(np.mean(np.square(now[now <= CUT])))), 4)}
        if mark in JOINT_LANDMARKS:
            m = joint_marks.index(mark)
            d = fit_offset(subjects, m)
            row.update(joint_rms=round(offset_rms(subjects, m, np.zeros(3)), 4), offset_mm=[round(1000 * float(v), 1) for v in d],
                       offset_rms=round(offset_rms(subjects, m, d), 4))
            if halves:
                held = [offset_rms(b, m, fit_offset(a, m)) for a, b in (halves, halves[::-1])]
                base = [offset_rms(b, m, np.zeros(3)) for _, b in (halves, halves[::-1])]
                row.update(heldout_joint_rms=round(float(np.mean(base)), 4), heldout_offset_rms=round(float(np.mean(held)), 4))
        rows.append(row)
    return {"target": "landmarks", "machine": machine(), "config": {"seed": config.seed, "subjects": config.subjects,
            "size": config.size, "frames": config.frames}, "frames_used": sum(len(f.height) for f in subjects),
            "cut": CUT, "min_confidence": MIN_CONFIDENCE, "rows": rows}


def landmarks_markdown(r: dict) -> str:
    c = r["config"]
    lines = [
        "# trioman bench landmarks: where MediaPipe's landmarks sit on Anny", "",
        f"Machine: {r['machine']}. Command: `trioman bench landmarks --seed {c['seed']} --subjects {c['subjects']} "
        f"--size {c['size']} --frames {c['frames']}`; {r['frames_used']} frames kept by the person model. Errors: RMS "
        "distance of the point's true projection to MediaPipe's keypoint, in person heights, over the frames where the "
        f"keypoint's confidence is >= {r['min_confidence']} and it lies within {r['cut']} person heights of the point "
        "(the rest are the wrong side's or a hidden limb's readings). Offsets: Anny's rest frame (+x the person's left, "
        "-y front, +z up), moved with the joint; held out: fitted on every other subject, scored on the rest, both ways.", "",
        "| landmark | point | offset used now (mm) | its error | at the joint | with the offset fitted | offset fitted (mm) "
        "| held out: at the joint | held out: with the offset |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for row in r["rows"]:
        cells = [f"{row['landmark']} {row['name']}", row["point"], str(row["offset_now_mm"]), str(row["now_rms"])]
        cells += ([str(row["joint_rms"]), str(row["offset_rms"]), str(row["offset_mm"]),
                   str(row.get("heldout_joint_rms", "")), str(row.get("heldout_offset_rms", ""))] if "offset_mm" in row else [""] * 5)
        lines.append("| " + " | ".join(cells) + " |")
    table = ", ".join(f"{row['landmark']}: ({', '.join(f'{v / 1000:.4f}' for v in row['offset_mm'])})"
                      for row in r["rows"] if row.get("heldout_offset_rms", 1.0) < row.get("heldout_joint_rms", 0.0))
    lines += ["", "`toolkit/fit/keypoints.py` `JOINT_OFFSETS` (m), fitted on every subject, for the landmarks whose offset "
              "brings them closer on the subjects it was not fitted on:", "",
              "```python", "{" + table + "}", "```", ""]
    return "\n".join(lines)
