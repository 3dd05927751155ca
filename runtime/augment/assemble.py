"""The end of an augment run: the pseudo-GT subject (``subject.json``, ``frames.npz``, ``body.npz``), the score
histogram and the complete augment.json, assembled from the records."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

import numpy as np

from trioman import __version__
from trioman.runtime.augment.histogram import draw_histogram
from trioman.runtime.augment.layout import AUGMENT_JSON, HISTOGRAM_PNG, STAGES, dump
from trioman.runtime.formats.common import write_npz
from trioman.runtime.formats.subject import (
    BODY_NPZ, FRAMES_NPZ, SUBJECT_FORMAT, SUBJECT_JSON, SUBJECT_VERSION, check_frames, check_subject_meta,
)
from trioman.runtime.outputs import atomic_path, atomic_write_bytes, atomic_write_text


def _stats(values: list[float]) -> dict[str, Any]:
    if not values:
        return {"count": 0, "mean": None, "min": None, "max": None}
    a = np.asarray(values, dtype=np.float64)
    return {"count": int(a.size), "mean": float(a.mean()), "min": float(a.min()), "max": float(a.max())}


def _write_subject(out: Path, subj: Any, frames: list[dict[str, Any]], records: list[dict[str, Any]],
                   settings: Mapping[str, Any]) -> None:
    """frames.npz, body.npz (the source's bytes) and subject.json of the accepted frames, each atomic."""
    seqs = [str(subj.sequence[r["source"]["index"]]) for r in records for _ in r["frames"]]
    meta = {
        "format": SUBJECT_FORMAT, "version": SUBJECT_VERSION, "body_model": subj.body_model, "units": "m",
        "up_axis": "z", "width": subj.width, "height": subj.height, "num_frames": len(frames),
        "background": [float(c) for c in subj.meta["background"]],
        "phenotype": dict(subj.meta.get("phenotype", {})),
        "generator": {"tool": "trioman augment", "version": __version__, "source_subject": settings["subject"]["path"],
                      "avatar": settings["avatar"]["path"], "seed": settings["seed"],
                      "per_frame": settings["per_frame"], "threshold": settings["threshold"],
                      "examiner": settings["examiner"] is not None,
                      "kind": "aligned" if settings["refiner"] is None else "refined",
                      "keep_carried": settings.get("keep_carried", False),
                      "mask": {"carried": "body mesh and source mask carried to the draw",
                               "alpha": "avatar render alpha"}[settings.get("mask", "alpha")]},
        "sequences": list(dict.fromkeys(seqs)),
    }
    where = out / SUBJECT_JSON
    check_subject_meta(meta, where)
    arrays = {
        "poses": np.array([f["pose"] for f in frames], dtype=np.float32),
        "trans": np.array([f["trans"] for f in frames], dtype=np.float32),
        "K": np.array([f["K"] for f in frames], dtype=np.float32),
        "viewmat": np.array([f["viewmat"] for f in frames], dtype=np.float32),
        "split": np.array(["train"] * len(frames), dtype=np.str_),
        "sequence": np.array(seqs, dtype=np.str_),
        "frame_names": np.array([f["name"] for f in frames], dtype=np.str_),
    }
    arrays = check_frames(arrays, out / FRAMES_NPZ, len(frames), subj.num_joints, meta["sequences"])
    atomic_write_bytes(out / BODY_NPZ, (Path(subj.root) / BODY_NPZ).read_bytes())
    with atomic_path(out / FRAMES_NPZ) as tmp:
        write_npz(tmp, arrays)
    atomic_write_text(where, dump(meta))  # last: a folder with subject.json is a complete subject


def finish(out: Path, subj: Any, records: list[dict[str, Any]], settings: dict[str, Any], header: dict[str, Any],
           with_examiner: bool, threshold: float | None, computed: int, seconds: float) -> dict[str, Any]:
    """The subject of the kept frames of ``records``, the histogram and augment.json (-> its content)."""
    frames = [f for r in records for f in r["frames"]]
    candidates = [c for r in records for c in r["candidates"]]
    by_status: dict[str, list[float]] = {s: [c["score"] for c in candidates if c["status"] == s]
                                         for s in ("accepted", "rejected", "not_chosen")}
    summary: dict[str, Any] = {
        "source_frames": len(records),
        "candidates": len(candidates),
        "frames_written": len(frames),
        "accepted": len(frames),
        "rejected": sum(1 for r in records if not r["kept"]),
        "not_chosen": len(by_status["not_chosen"]),
        "scores": _stats([c["score"] for c in candidates if c["score"] is not None]),
        "chosen_scores": _stats(by_status["accepted"] + by_status["rejected"]),
    }
    if frames:
        _write_subject(out, subj, frames, records, settings)
        summary["subject_written"] = True
        summary["note"] = f"{len(frames)} pseudo-GT frames written as a subject (this folder)"
    else:
        for name in (SUBJECT_JSON, FRAMES_NPZ, BODY_NPZ):
            (out / name).unlink(missing_ok=True)
        summary["subject_written"] = False
        summary["note"] = "0 accepted: no pseudo-GT subject written (a subject needs at least one frame)"
    hist = out / HISTOGRAM_PNG
    if with_examiner:
        draw_histogram(by_status, threshold, hist)
        summary["histogram"] = HISTOGRAM_PNG  # relative to the output folder
    else:
        hist.unlink(missing_ok=True)
        summary["histogram"] = None
    n = max(len(records), 1)
    timing = {
        "ms_per_source_frame": {s: 1000.0 * sum(r["seconds"][s] for r in records) / n for s in STAGES},
        "frames_computed": computed,
        "frames_resumed": len(records) - computed,
        "seconds_this_call": seconds,
    }
    timing["ms_per_source_frame"]["total"] = sum(timing["ms_per_source_frame"].values())
    result = dict(header, status="complete", summary=summary, timing=timing)
    atomic_write_text(out / AUGMENT_JSON, dump(result))
    return result
