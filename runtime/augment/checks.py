"""The arguments of an augment run and its output folder, checked before any work. Errors name the parameter
and the value (docs/design.md, "Conventions": errors name what the caller gave)."""

from __future__ import annotations

import json
import numbers
import os
import re
from pathlib import Path
from typing import Any, Iterable

from trioman.runtime.augment.layout import AUGMENT_JSON, HISTOGRAM_PNG, RECORDS_DIR
from trioman.runtime.formats.subject import (
    BODY_NPZ, FRAMES_NPZ, IMAGES_DIR, MASKS_DIR, SUBJECT_JSON, WEIGHTS_DIR,
)
from trioman.runtime.outputs import is_temp_name


MAX_PER_FRAME = 64  # candidates per source frame (each is a render, a Refiner pass and an Examiner score)


def check_options(per_frame: Any, threshold: Any, seed: Any, frames: Any, limit: Any, examiner: Any,
                  resume: bool, overwrite: bool) -> None:
    def integer(v: Any) -> bool:
        return isinstance(v, numbers.Integral) and not isinstance(v, bool)

    if not integer(per_frame) or not 1 <= per_frame <= MAX_PER_FRAME:
        raise ValueError(f"per_frame: must be an integer in [1, {MAX_PER_FRAME}], got {per_frame!r}")
    if threshold is not None:
        if isinstance(threshold, bool) or not isinstance(threshold, numbers.Real) or not 0.0 <= threshold <= 1.0:
            raise ValueError(f"threshold: must be a number in [0, 1], got {threshold!r}")
        if examiner is None:
            raise ValueError(f"threshold: {threshold} needs an Examiner (`examiner`); without one every candidate is kept")
    if not integer(seed) or seed < 0:
        raise ValueError(f"seed: must be an integer >= 0, got {seed!r}")
    if frames not in ("train", "all"):
        raise ValueError(f"frames: expected 'train' or 'all', got {frames!r}")
    if limit is not None and (not integer(limit) or limit < 1):
        raise ValueError(f"limit: must be an integer >= 1, got {limit!r}")
    if resume and overwrite:
        raise ValueError("resume and overwrite: choose one (continue the run in `out`, or replace it)")


def check_keep_carried(keep_carried: Any, refiner: Any) -> None:
    if keep_carried is not None and not isinstance(keep_carried, bool):
        raise ValueError(f"keep_carried: must be true, false or None (with a Refiner: true), got {keep_carried!r}")
    if keep_carried and refiner is None:
        raise ValueError("keep_carried: takes the Refiner's output where nothing was carried; give `refiner` too "
                         "(without a Refiner the pseudo-GT is the aligned kind, which keeps the carried pixels already)")


def existing(path: Any, name: str, kind: str) -> Path:
    """``path`` (the argument ``name``, a ``kind``) as a Path, or FileNotFoundError naming both."""
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"{name}: {kind} not found: {p}")
    return p


def check_out(out: Path, resume: bool, overwrite: bool) -> bool:
    """-> whether ``out`` holds earlier output (non-empty). Raises before any work when it may not be used."""
    if out.exists() and not out.is_dir():
        raise FileExistsError(f"out: {out} exists and is not a folder")
    if not out.is_dir() or not any(out.iterdir()):
        return False
    is_augment = (out / AUGMENT_JSON).is_file()
    if not (resume or overwrite):
        raise FileExistsError(f"out: {out} exists and is not empty (pass `resume` to continue an interrupted run "
                              f"there, `overwrite` to replace it, or choose another `out`)")
    action = "resume" if resume else "replace"
    if not is_augment:
        raise FileExistsError(f"out: {out} is not empty and holds no {AUGMENT_JSON}: not a `trioman augment` "
                              f"output, refusing to {action} it")
    for root, dirs, files in os.walk(out):  # a link would send the writes (and an overwrite's removals) elsewhere
        for name in dirs + files:
            if (Path(root) / name).is_symlink():
                raise FileExistsError(f"out: {Path(root) / name} is a link, which trioman augment never writes; "
                                      f"refusing to {action} {out}")
    return True


def written_files(out: Path, source_names: Iterable[str]) -> list[Path]:
    """The files and folders in ``out`` that ``trioman augment`` wrote: the fixed names, the records, the frames
    they list, the frames of an interrupted source frame (``<source name>_c<k>.png``, no record yet) and
    temporary files. Anything else is a FileExistsError naming it: ``overwrite`` removes only its own output."""
    fixed = {AUGMENT_JSON, SUBJECT_JSON, BODY_NPZ, FRAMES_NPZ, HISTOGRAM_PNG, IMAGES_DIR, MASKS_DIR, RECORDS_DIR,
             WEIGHTS_DIR}
    records, frames = set(), set()
    for path in (out / RECORDS_DIR).glob("*.json"):
        try:
            rec = json.loads(path.read_text(encoding="utf-8"))
            names = {f"{f['name']}.png" for f in rec["frames"]}
        except (ValueError, KeyError, TypeError):
            continue  # not a record of ours: reported below
        records.add(path.name)
        frames |= names
    orphan = re.compile("(?:" + "|".join(re.escape(n) for n in source_names) + r")_c\d+\.png")
    owned = []
    for root, dirs, files in os.walk(out):
        parts = Path(root).relative_to(out).parts
        for name in sorted(dirs) + sorted(files):
            path = Path(root) / name
            if (is_temp_name(name) or (not parts and name in fixed) or (parts == (RECORDS_DIR,) and name in records)
                    or (parts in ((IMAGES_DIR,), (MASKS_DIR,), (WEIGHTS_DIR,)) and (name in frames or orphan.fullmatch(name)))):
                owned.append(path)
            else:
                raise FileExistsError(f"overwrite: {path} was not written by trioman augment; refusing to replace "
                                      f"{out} (move it away, or choose another `out`)")
        dirs[:] = [d for d in dirs if not is_temp_name(d)]
    return owned


def check_joints(avatar: Any, subject: Any, avatar_path: Path) -> None:
    a, s = avatar.skeleton.joint_names, subject.body.skeleton.joint_names
    if len(a) != len(s):
        raise ValueError(f"avatar: {avatar_path} has {len(a)} joints, but the subject's body has {len(s)} joints "
                         f"(the avatar must be trained on this subject's body)")
    if a != s:
        j = next(k for k in range(len(a)) if a[k] != s[k])
        raise ValueError(f"avatar: joint {j} is {a[j]!r} in {avatar_path}, but {s[j]!r} in the subject's body "
                         f"(the avatar must be trained on this subject's body)")
