"""The augment run of tests/runtime/test_augment.py that tests/runtime/test_shards.py compares its shards with:
its frame limit, the run with the tests' settings, and a snapshot of its output."""

import json
from pathlib import Path

from trioman.runtime.augment import AUGMENT_JSON, augment

LIMIT = 4  # source frames of the main runs (--frames all: the tiny subject has 2 train + 4 test frames)


def run(inputs, out, examiner=True, **kw):
    kw = {"frames": "all", "limit": LIMIT, "seed": 7, "progress": False, "keep_carried": False, **kw}  # the Refiner's frames
    return augment(inputs.subject, inputs.avatar, inputs.refiner, out, inputs.examiner if examiner else None, **kw)


def snapshot(out: Path) -> dict:
    """Every file's bytes; augment.json and the records as JSON without their timings."""
    files = {}
    for p in sorted(out.rglob("*")):
        if p.is_file():
            rel = p.relative_to(out).as_posix()
            if rel == AUGMENT_JSON or rel.startswith("records/"):
                d = json.loads(p.read_text())
                d.pop("timing" if rel == AUGMENT_JSON else "seconds")
                files[rel] = d
            else:
                files[rel] = p.read_bytes()
    return files
