"""``trioman bench landmarks``: where MediaPipe's pose landmarks sit on the Anny body, measured on realistic
synthetic subjects whose true poses and cameras are known: for each landmark, the body point (a rest vertex or a
joint, within ``REACH`` of the point ``toolkit/fit/keypoints.py`` uses now) whose projection lies closest to
MediaPipe's keypoint over every frame the person model keeps, confidence-weighted, in units of the person's
height. The report lists both points' errors and the table ``keypoints.py`` takes (``CALIBRATED``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from trioman.bench.common import machine
from trioman.bench.config import LandmarksBenchConfig

REACH = 0.12  # m: candidates within this of the current point, in the rest pose


def bench_landmarks(config: LandmarksBenchConfig) -> dict:
    from trioman.runtime.cameras import project
    from trioman.runtime.formats import load_subject
    from trioman.runtime.person import PersonTracker
    from trioman.runtime.person.landmarks import KEYPOINT_NAMES
    from trioman.toolkit.fit.keypoints import correspondence
    from trioman.toolkit.synth.subject import SynthConfig, TruthRenderer, synthesize_subject

    work = Path(config.out) / "landmarks_work"
    tracker = PersonTracker()
    cost: np.ndarray | None = None  # [33, V + J] weighted squared error, in person heights
    weight = np.zeros(33)
    frames_used = 0
    for k in range(config.subjects):
        seed = config.seed + k
        folder = work / f"s{seed}"
        if not (folder / "subject.json").is_file():
            synthesize_subject(SynthConfig(seed=seed, size=config.size, frames=config.frames, aspect=9 / 16, style="realistic"),
                               folder, overwrite=True, progress=False)
        s = load_subject(folder)
        truth = TruthRenderer(s)
        body = s.body
        sk = body.skeleton
        corr = correspondence(body)
        previous = None
        for i in range(s.num_frames):
            if s.sequence[i] != previous:
                tracker.reset()
                previous = s.sequence[i]
            frame, _, mask = truth.recorded(i)
            p = tracker(np.rint(np.clip(frame, 0, 1) * 255).astype(np.uint8))
            if not p.ok:
                continue
            frames_used += 1
            pose, trans = s.poses_true[i].astype(np.float64), s.trans[i].astype(np.float64)
            points = np.concatenate([body.pose(pose, trans), sk.forward_kinematics(pose, trans)[:, :3, 3]])
            uv, _ = project(points, s.viewmat[i].astype(np.float64), s.K[i].astype(np.float64))
            rows = np.flatnonzero(mask.max(axis=1) >= 0.5)
            height = float(rows[-1] - rows[0] + 1) if len(rows) > 1 else float(s.height)
            d2 = ((uv[None] - p.keypoints[:, None]) ** 2).sum(-1) / height ** 2  # [33, V + J]
            cost = d2 * p.confidence[:, None] if cost is None else cost + d2 * p.confidence[:, None]
            weight += p.confidence
    if cost is None:
        raise ValueError("landmarks: the person model kept no frame of the calibration subjects")
    rest = np.concatenate([body.vertices, sk.joints])
    V = body.num_vertices
    rows = []
    for m, j, v in zip(corr.landmarks, corr.joint, corr.vertex):
        now = V + j if j >= 0 else v
        near = np.flatnonzero(np.linalg.norm(rest - rest[now], axis=1) <= REACH)
        best = near[np.argmin(cost[m, near])]
        rms = lambda c: float(np.sqrt(cost[m, c] / max(weight[m], 1e-9)))  # noqa: E731
        rows.append({"landmark": int(m), "name": KEYPOINT_NAMES[m], "now": _label(now, V, sk), "now_rms": round(rms(now), 4),
                     "best": _label(best, V, sk), "best_rms": round(rms(best), 4),
                     "moved_mm": round(1000 * float(np.linalg.norm(rest[best] - rest[now])), 1)})
    return {"target": "landmarks", "machine": machine(), "config": {"seed": config.seed, "subjects": config.subjects,
            "size": config.size, "frames": config.frames}, "frames_used": frames_used, "rows": rows}


def _label(index: int, V: int, sk) -> str:
    return f"joint {sk.joint_names[index - V]}" if index >= V else f"vertex {index}"


def landmarks_markdown(r: dict) -> str:
    c = r["config"]
    lines = [
        "# trioman bench landmarks: where MediaPipe's landmarks sit on Anny", "",
        f"Machine: {r['machine']}. Command: `trioman bench landmarks --seed {c['seed']} --subjects {c['subjects']} "
        f"--size {c['size']} --frames {c['frames']}`; {r['frames_used']} frames kept by the person model. Errors: RMS "
        "distance of the point's true projection to MediaPipe's keypoint, confidence-weighted, in person heights.", "",
        "| landmark | point used now | its error | best point near it | its error | moved (mm, rest pose) |",
        "|---|---|---|---|---|---|",
    ]
    for row in r["rows"]:
        lines.append(f"| {row['landmark']} {row['name']} | {row['now']} | {row['now_rms']} | {row['best']} | "
                     f"{row['best_rms']} | {row['moved_mm']} |")
    table = ", ".join(f"{row['landmark']}: {row['best'].split()[1]!r}" if row["best"].startswith("joint")
                      else f"{row['landmark']}: {int(row['best'].split()[1])}" for row in r["rows"])
    lines += ["", "`toolkit/fit/keypoints.py` `CALIBRATED` (a joint name or a vertex index per landmark):", "",
              "```python", "{" + table + "}", "```", ""]
    return "\n".join(lines)
