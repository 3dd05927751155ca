"""``merge=True``: the shards' frames and records (runtime/shards.py) moved into the output and assembled as one
process would."""

from __future__ import annotations

import os
import shutil
import time
from pathlib import Path
from typing import Any

import numpy as np

from trioman.runtime.augment.assemble import finish
from trioman.runtime.augment.layout import RECORDS_DIR, record_path, running_header
from trioman.runtime.augment.records import check_record, read_record
from trioman.runtime.augment.step import frame_seed
from trioman.runtime.formats.common import FormatError, read_json
from trioman.runtime.formats.subject import IMAGES_DIR, MASKS_DIR, WEIGHTS_DIR
from trioman.runtime.shards import SHARDS_DIR, Shard


def merge(out: Path, subj: Any, selection: np.ndarray, shards: list[dict[str, Any]], settings: dict[str, Any],
          with_examiner: bool, threshold: float | None) -> dict[str, Any]:
    """Check every shard's records and files, then move them into ``out`` (a record last, so a merge can be
    rerun), assemble ``out`` from the records in selection order and remove out/shards. A malformed record
    or a missing file is a FormatError naming it, raised before anything moves."""
    start = time.perf_counter()
    index_of = {str(subj.frame_names[i]): int(i) for i in selection.tolist()}
    moves: list[tuple[Path, Path]] = []
    for rec in shards:
        folder = out / SHARDS_DIR / Shard.parse(rec["shard"]).name
        for name in rec["items"]:
            src = record_path(folder, name)
            if not src.is_file():
                if record_path(out, name).is_file():  # moved by an earlier merge
                    continue
                raise ValueError(f"merge: shard {rec['shard']} has no record for frame {name} ({src})")
            index = index_of.get(name, -1)
            rec_ = check_record(read_json(src), src, folder, name, index)
            expected = frame_seed(settings["seed"], index)
            if rec_["seed"] != expected:  # another run's frame
                raise FormatError(f"{src}: seed: expected {expected} (the run's seed {settings['seed']} for frame "
                                  f"{name}), got {rec_['seed']}")
            for f in rec_["frames"]:
                for sub in (IMAGES_DIR, MASKS_DIR) + ((WEIGHTS_DIR,) if f.get("weights") else ()):
                    file = folder / sub / f"{f['name']}.png"
                    if file.is_symlink() or not file.is_file():  # a link would bring in what lies elsewhere
                        raise FormatError(f"{file}: expected a file written by the shard's job, found "
                                          f"{'a link' if file.is_symlink() else 'no file'}")
                    moves.append((file, out / sub / f"{f['name']}.png"))
            moves.append((src, record_path(out, name)))
    for d in (out / IMAGES_DIR, out / MASKS_DIR, out / RECORDS_DIR, out / WEIGHTS_DIR):
        d.mkdir(parents=True, exist_ok=True)
    for src, dst in moves:
        os.replace(src, dst)
    records = []
    for i in selection.tolist():
        rec = read_record(out, str(subj.frame_names[i]), i)
        if rec is None:
            raise ValueError(f"merge: frame {subj.frame_names[i]} has no complete record in {out / RECORDS_DIR}")
        records.append(rec)
    result = finish(out, subj, records, settings, running_header(settings), with_examiner, threshold, 0,
                    time.perf_counter() - start)
    shutil.rmtree(out / SHARDS_DIR)
    return result
