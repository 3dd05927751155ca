"""Wall time and peak resident memory (RSS) of a process's stages, one printed line per stage.

On Linux the peak is the process's VmHWM (/proc/self/status), reset at the start of each stage by
writing "5" to /proc/self/clear_refs, so each stage reports its own peak. Where that reset is not
available the peak is ``resource.getrusage`` ru_maxrss, a high-water mark since the process started
(a stage then reports the peak so far).
"""

from __future__ import annotations

import contextlib
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterator

_STATUS = Path("/proc/self/status")
_CLEAR_REFS = Path("/proc/self/clear_refs")


def reset_peak_rss() -> bool:
    """Reset the process's resident high-water mark; -> whether it could be reset."""
    try:
        _CLEAR_REFS.write_text("5")
        return True
    except OSError:
        return False


def peak_rss_bytes() -> int:
    """The process's peak resident memory (bytes) since its start or the last reset."""
    try:
        for line in _STATUS.read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) * 1024  # reported in kB
    except OSError:
        pass
    import resource

    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak if sys.platform == "darwin" else peak * 1024  # bytes on macOS, kB elsewhere


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


def mib(n: int) -> float:
    return n / 2**20
