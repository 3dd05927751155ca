"""A source frame's record (``records/<name>.json``): read back on resume, checked in full at a merge."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any, Callable

import numpy as np

from trioman.runtime.augment.layout import AUGMENT_VERSION, record_path
from trioman.runtime.formats import FormatError
from trioman.runtime.formats.avatar import sha256_file
from trioman.runtime.formats.subject import IMAGES_DIR, MASKS_DIR, WEIGHTS_DIR, check_frame_name

_SHA256 = re.compile(r"[0-9a-f]{64}")  # a frame file's digest in its record (fullmatch)


def read_record(out: Path, name: str, index: int) -> dict[str, Any] | None:
    """A finished frame's record, or None when the frame must be (re)done."""
    path = record_path(out, name)
    if not path.is_file():
        return None
    try:
        rec = json.loads(path.read_text(encoding="utf-8"))
        ok = rec["version"] == AUGMENT_VERSION and rec["source"]["index"] == index
        files = [out / d / f"{f['name']}.png" for f in rec["frames"]
                 for d in (IMAGES_DIR, MASKS_DIR) + ((WEIGHTS_DIR,) if f.get("weights") else ())]
    except (OSError, ValueError, KeyError, TypeError):
        return None
    return rec if ok and all(f.is_file() for f in files) else None


def check_record(rec: Any, path: Path, folder: Path, name: str, index: int) -> dict[str, Any]:
    """A source frame's record as augment writes it, its frames' files present in ``folder``: -> ``rec``; a
    FormatError naming ``path`` and the field otherwise (a merge reads records another job wrote)."""
    def fail(field: str, why: str) -> FormatError:
        return FormatError(f"{path}: {field}: {why}")

    if not isinstance(rec, dict):
        raise fail("record", f"expected a JSON object, got {type(rec).__name__}")
    if rec.get("version") != AUGMENT_VERSION:
        raise fail("version", f"expected {AUGMENT_VERSION}, got {rec.get('version')!r}")
    source = rec.get("source")
    if not isinstance(source, dict) or source.get("name") != name or source.get("index") != index:
        raise fail("source", f"expected frame {name!r} (index {index}), got {source!r}")
    if isinstance(rec.get("seed"), bool) or not isinstance(rec.get("seed"), int):
        raise fail("seed", f"expected an integer, got {rec.get('seed')!r}")
    candidates, frames = rec.get("candidates"), rec.get("frames")
    if not isinstance(candidates, list) or not isinstance(frames, list):
        raise fail("candidates/frames", "expected lists")
    for k, c in enumerate(candidates):
        score = c.get("score") if isinstance(c, dict) else "not an object"
        if score is not None and (isinstance(score, bool) or not isinstance(score, (int, float))
                                  or not 0.0 <= score <= 1.0):
            raise fail(f"candidates[{k}].score", f"expected null or a number in [0, 1], got {score!r}")
    shapes = {"pose": None, "trans": (3,), "viewmat": (4, 4), "K": (3, 3)}
    for k, f in enumerate(frames):
        if not isinstance(f, dict):
            raise fail(f"frames[{k}]", "expected an object")
        check_frame_name(f.get("name"), path, f"frames[{k}].name")
        for key, shape in shapes.items():
            try:
                a = np.asarray(f.get(key), dtype=np.float64)
            except (TypeError, ValueError):
                raise fail(f"frames[{k}].{key}", "expected numbers") from None
            if (shape is not None and a.shape != shape) or a.size == 0 or not np.isfinite(a).all():
                raise fail(f"frames[{k}].{key}", f"expected finite numbers of shape {shape or '[J, 3]'}, got {list(a.shape)}")
        subs = (IMAGES_DIR, MASKS_DIR) + ((WEIGHTS_DIR,) if f.get("weights") else ())
        for sub in subs:
            if not (folder / sub / f"{f['name']}.png").is_file():
                raise fail(f"frames[{k}]", f"its file {folder / sub / (f['name'] + '.png')} is missing")
        if "sha256" in f:  # records written before the hashes were kept have none, and stay readable
            _check_frame_hashes(f["sha256"], subs, folder, f["name"], fail, f"frames[{k}].sha256")
    return rec


def _check_frame_hashes(digests: Any, subs: tuple[str, ...], folder: Path, name: str, fail: Callable[[str, str], FormatError],
                       field: str) -> None:
    """Each of a frame's files (``folder/<sub>/<name>.png``) has the sha256 its record gives (``digests``:
    {sub: hex digest}, one per file): a file replaced or damaged after it was written is named."""
    if not isinstance(digests, dict) or sorted(digests) != sorted(subs) or not all(
            isinstance(d, str) and _SHA256.fullmatch(d) for d in digests.values()):
        raise fail(field, f"expected {{{', '.join(repr(s) for s in subs)}}} each a sha256 (64 hex digits), got {digests!r}")
    for sub in subs:
        path = folder / sub / f"{name}.png"
        found = sha256_file(path)
        if found != digests[sub]:
            raise fail(f"{field}.{sub}", f"{path} is not the file that was written (its sha256 is {found[:12]}..., the "
                                         f"record's {digests[sub][:12]}...): replaced or damaged since")
