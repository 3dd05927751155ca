"""Per-stage wall-clock timers: the renderers and the avatar's training step mark their stages with
:func:`stage`; a benchmark collects them with :func:`record_stages`. Outside a record a mark costs one
context-variable read.

Stages nest: a stage's time excludes the stages inside it, so the record's values add up to the
wall time of the marked work.
"""

from __future__ import annotations

import contextlib
import time
from contextvars import ContextVar
from typing import Iterator

_RECORD: ContextVar[dict[str, float] | None] = ContextVar("trioman_stage_record", default=None)
_INNER: ContextVar[list[float] | None] = ContextVar("trioman_stage_inner", default=None)


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
