"""What an augment run records about its inputs (augment.json's ``settings``), and what a resumed run must share
with the run it continues."""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path
from typing import Any, Mapping

from trioman.runtime.augment.layout import AUGMENT_JSON
from trioman.runtime.formats import FormatError
from trioman.runtime.formats.avatar import AVATAR_JSON, sha256_file
from trioman.runtime.formats.subject import FRAMES_NPZ
from trioman.runtime.generator import GeneratorConfig

# What a resumed run must share with the run it continues (everything that decides the output bytes).
RESUME_KEYS = ("subject", "avatar", "refiner", "examiner", "seed", "per_frame", "threshold", "frames", "mask",
               "keep_carried", "generator")
# Settings that runs of earlier versions did not record, as those runs had them.
UNRECORDED = {"keep_carried": False}


def model_info(model: Any, path: Path) -> dict[str, Any]:
    meta = dict(model.meta)
    return {"path": str(path.resolve()), "sha256": sha256_file(path), "size": list(model.size),
            "config_hash": meta.get("trioman.config_hash"), "precision": meta.get("trioman.precision"),
            "kind": meta.get("trioman.kind"), "version": meta.get("trioman.version")}


def run_settings(subject: Any, avatar: Any, avatar_path: Path, refiner: Any, refiner_path: Path | None, examiner: Any,
                 examiner_path: Path | None, seed: int, per_frame: int, threshold: float | None, frames: str,
                 gen_cfg: GeneratorConfig, mask: str, keep_carried: bool) -> dict[str, Any]:
    source = dict(avatar.meta.get("source", {}))
    ref = None
    if refiner is not None:
        ref = model_info(refiner, refiner_path)
        ref["conditions"] = refiner.conditions
    return {
        "subject": {"path": str(Path(subject.root).resolve()),
                    "frames_sha256": sha256_file(Path(subject.root) / FRAMES_NPZ)},
        "avatar": {"path": str(avatar_path.resolve()), "avatar_json_sha256": sha256_file(avatar_path / AVATAR_JSON),
                   "step": source.get("step"), "run": source.get("run"), "num_gaussians": avatar.num_gaussians},
        "refiner": ref,
        "examiner": None if examiner is None else model_info(examiner, examiner_path),
        "seed": int(seed),
        "per_frame": int(per_frame),
        "threshold": None if threshold is None else float(threshold),
        "frames": frames,
        "mask": mask,
        "keep_carried": bool(keep_carried),
        "generator": json.loads(json.dumps(asdict(gen_cfg))),
    }


def check_resume(out: Path, settings: Mapping[str, Any]) -> None:
    """The earlier run in ``out`` ran with ``settings`` (every one of RESUME_KEYS), or a ValueError naming the first
    that differs, both values."""
    try:
        old = json.loads((out / AUGMENT_JSON).read_text(encoding="utf-8"))["settings"]
    except (OSError, ValueError, KeyError, TypeError) as err:
        raise FormatError(f"{out / AUGMENT_JSON}: unreadable settings of the earlier run ({err})") from None
    for key in RESUME_KEYS:
        was = old.get(key, UNRECORDED.get(key))
        if was != settings[key]:
            raise ValueError(f"resume: {key} differs from the run in {out} (was {was!r}, now "
                             f"{settings[key]!r}); use the same inputs, or `overwrite` to start again")
