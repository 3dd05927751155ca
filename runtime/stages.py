"""Stage timing, in one place: the marks that the renderers and the avatar's training step put on their
stages (``stage``, collected by a benchmark with ``record_stages``), a command's printed stage lines with
their peak resident memory (``StageLog``), and the process's peak memory (``peak_rss_bytes``,
``lifetime_peak_rss_bytes``).

Marks: outside a record a mark costs one context-variable read. They nest: a stage's time excludes the
stages inside it, so the record's values add up to the wall time of the marked work.

Peaks: on Linux the peak is the process's VmHWM (/proc/self/status), reset at the start of each
``StageLog`` stage by writing "5" to /proc/self/clear_refs, so each stage reports its own peak. Where that
reset is not available the peak is ``resource.getrusage`` ru_maxrss, a high-water mark since the process
started (a stage then reports the peak so far). ``lifetime_peak_rss_bytes`` is always that since-start
mark: what a benchmark reports for its whole process.
"""

from __future__ import annotations

import contextlib
import sys
import time
from contextvars import ContextVar
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterator

_RECORD: ContextVar[dict[str, float] | None] = ContextVar("trioman_stage_record", default=None)
_INNER: ContextVar[list[float] | None] = ContextVar("trioman_stage_inner", default=None)
_STATUS = Path("/proc/self/status")
_CLEAR_REFS = Path("/proc/self/clear_refs")


# --------------------------------------------------------------------------------------------------
# marks inside the work, collected by a benchmark


@contextlib.contextmanager
def stage(name: str) -> Iterator[None]:
    """Add the block's wall time, less that of the stages inside it, to ``name`` in the active record."""
    record = _RECORD.get()
    if record is None:
        yield
        return
    inner = [0.0]
    token = _INNER.set(inner)
    t0 = time.perf_counter()
    try:
        yield
    finally:
        elapsed = time.perf_counter() - t0
        _INNER.reset(token)
        record[name] = record.get(name, 0.0) + elapsed - inner[0]
        outer = _INNER.get()
        if outer is not None:
            outer[0] += elapsed


@contextlib.contextmanager
def record_stages() -> Iterator[dict[str, float]]:
    """-> a dict that collects seconds per stage name for the marks inside the block (in first-seen order)."""
    record: dict[str, float] = {}
    token = _RECORD.set(record)
    outer = _INNER.set(None)
    try:
        yield record
    finally:
        _INNER.reset(outer)
        _RECORD.reset(token)


# --------------------------------------------------------------------------------------------------
# peak resident memory


def reset_peak_rss() -> bool:
    """Reset the process's resident high-water mark; -> whether it could be reset."""
    try:
        _CLEAR_REFS.write_text("5")
        return True
    except OSError:
        return False


def lifetime_peak_rss_bytes() -> int:
    """The process's peak resident memory (bytes) since it started, whatever was reset (ru_maxrss)."""
    import resource

    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak if sys.platform == "darwin" else peak * 1024  # bytes on macOS, kB elsewhere


def peak_rss_bytes() -> int:
    """The process's peak resident memory (bytes) since its start or the last reset."""
    try:
        for line in _STATUS.read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) * 1024  # reported in kB
    except OSError:
        pass
    return lifetime_peak_rss_bytes()


def mib(n: int) -> float:
    return n / 2**20


# --------------------------------------------------------------------------------------------------
# a command's stages, one printed line each


@dataclass(frozen=True)
class Stage:
    name: str
    seconds: float
    peak_rss: int  # bytes


@dataclass
class StageLog:
    """Times stages and records each one's peak RSS; ``say`` gets one line per finished stage."""

    say: Callable[[str], None] = print
    stages: list[Stage] = field(default_factory=list)

    @contextlib.contextmanager
    def stage(self, name: str) -> Iterator[None]:
        reset = reset_peak_rss()
        start = time.perf_counter()
        yield
        s = Stage(name, time.perf_counter() - start, peak_rss_bytes())
        self.stages.append(s)
        self.say(f"stage {s.name:<14s} {s.seconds:6.1f} s   peak RSS {mib(s.peak_rss):6.0f} MiB"
                 + ("" if reset else " (since start)"))

    @property
    def peak_rss(self) -> int:
        """The highest peak of all stages so far (bytes)."""
        return max((s.peak_rss for s in self.stages), default=peak_rss_bytes())

    @property
    def seconds(self) -> float:
        return sum(s.seconds for s in self.stages)
