"""Shards of a long job (``shard`` and ``merge``: the commands' ``--shard I/N`` and ``--merge``; docs/scaling.md):
N independent jobs, on one machine or many sharing a folder, each own the items at positions p with p % N == I
(whole subjects of a corpus, whole source frames of an augment run) and write only their own files,
atomically. A shard records its status in ``<out>/shards/I-of-N.json`` ("running", then "complete" or
"failed" with the error) and holds ``<out>/shards/I-of-N.lock``, created exclusively, while it runs, so two
jobs of one shard never run together; the merge reads every record, refuses a missing, unfinished or failed
shard or one run with other settings, naming it, and then assembles the final files as one process would."""

from __future__ import annotations

import json
import re
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator, Mapping, Sequence

from trioman.runtime.outputs import atomic_write_text, writer_lock

__all__ = ["SHARDS_DIR", "Shard", "shard_run", "check_shards"]

SHARDS_DIR = "shards"
_NAME = re.compile(r"(\d+)-of-(\d+)\.json")  # fullmatch


@dataclass(frozen=True)
class Shard:
    index: int  # I, from 0
    count: int  # N

    def __post_init__(self) -> None:
        if not (isinstance(self.index, int) and isinstance(self.count, int) and 0 <= self.index < self.count):
            raise ValueError(f"shard: expected I/N with 0 <= I < N, got {self.index}/{self.count}")

    @classmethod
    def parse(cls, text: str) -> "Shard":
        """"I/N" -> Shard(I, N)."""
        m = re.fullmatch(r"(\d+)/(\d+)", text.strip())
        if m is None or not 0 <= int(m[1]) < int(m[2]):
            raise ValueError(f"shard: expected I/N with 0 <= I < N (e.g. 0/4), got {text!r}")
        return cls(int(m[1]), int(m[2]))

    @property
    def name(self) -> str:
        """The shard's file and folder name, "I-of-N"."""
        return f"{self.index}-of-{self.count}"

    def __str__(self) -> str:
        return f"{self.index}/{self.count}"

    def owns(self, position: int) -> bool:
        """The rule: the item at ``position`` (in the job's order) belongs to shard position % N."""
        return position % self.count == self.index

    def take(self, items: Sequence[Any]) -> list[Any]:
        """This shard's items of ``items``, in order."""
        return [x for p, x in enumerate(items) if self.owns(p)]

    def record_path(self, out: Path) -> Path:
        return Path(out) / SHARDS_DIR / f"{self.name}.json"


def _write(path: Path, record: Mapping[str, Any]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(path, json.dumps(record, indent=2, allow_nan=False) + "\n")


@contextmanager
def shard_run(out: str | Path, shard: Shard, settings: Mapping[str, Any], items: Sequence[str]) -> Iterator[None]:
    """The shard's record around its work: "running" before, "complete" after, "failed" with the
    error when the work raises (the error goes on). ``settings`` must be JSON and equal the merge's;
    ``items`` names what the shard owns. The shard's lock (``I-of-N.lock``, an exclusive create) is held
    throughout: a second job of the same shard is refused before it writes anything."""
    path = shard.record_path(Path(out))
    with writer_lock(path.with_suffix(".lock"), f"shard {shard}: another job of this shard"):
        record = {"shard": str(shard), "settings": settings, "items": list(items)}
        _write(path, {**record, "status": "running"})
        try:
            yield
        except BaseException as err:
            _write(path, {**record, "status": "failed", "error": f"{type(err).__name__}: {err}"})
            raise
        _write(path, {**record, "status": "complete"})


# augment keeps an interrupted shard's finished frames only with --resume (synth-corpus skips finished subjects
# itself): a hint naming that command's flag, the same for the users of both commands
_RERUN = " (augment: with --resume as well)"


def check_shards(out: str | Path, settings: Mapping[str, Any]) -> list[dict[str, Any]]:
    """The records of every shard of ``out``, in shard order, after checking that all N exist, finished
    and ran with ``settings``; a ValueError naming ``merge`` and the shard otherwise."""
    folder = Path(out) / SHARDS_DIR
    found = sorted((int(m[1]), int(m[2])) for p in (folder.iterdir() if folder.is_dir() else ())
                   if (m := _NAME.fullmatch(p.name)))
    if not found:
        raise ValueError(f"merge: no shard records in {folder} (run the jobs with `shard` I/N first)")
    counts = sorted({n for _, n in found})
    if len(counts) > 1:
        raise ValueError(f"merge: {folder} holds shards of different counts N ({', '.join(map(str, counts))}); "
                         f"remove the records of the runs you do not mean")
    records = []
    for shard in (Shard(i, counts[0]) for i in range(counts[0])):
        path = shard.record_path(Path(out))
        if not path.is_file():
            raise ValueError(f"merge: shard {shard} is missing: no {path} (run the job with `shard` {shard})")
        try:
            rec = json.loads(path.read_text(encoding="utf-8"))
            status = rec["status"]
        except (OSError, ValueError, KeyError, TypeError) as err:
            raise ValueError(f"merge: shard {shard}: unreadable record {path} ({err})") from None
        if status == "failed":
            raise ValueError(f"merge: shard {shard} failed ({rec.get('error')}); run it again with `shard` {shard}"
                             f"{_RERUN}")
        if status != "complete":
            raise ValueError(f"merge: shard {shard} did not finish (status {status!r} in {path}); "
                             f"run it again with `shard` {shard}{_RERUN}")
        theirs = rec.get("settings", {})
        for key in sorted(set(settings) | set(theirs)):
            if theirs.get(key) != settings.get(key):
                raise ValueError(f"merge: shard {shard} ran with other settings ({key}: {theirs.get(key)!r}, "
                                 f"the merge has {settings.get(key)!r})")
        records.append(rec)
    return records
