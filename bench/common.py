"""What every benchmark shares: the machine line, timing, batched model calls, the report
files (``TARGET.json`` and ``TARGET.md`` in the report folder) and the checks of the targets' configs. Timings
are wall clock on the machine named in the report; nothing in trioman.bench is a timed test. Stage timing and
peak memory: trioman.runtime.stages."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any


def check_names(config: Any, name: str) -> None:
    """ValueError naming the field ``name`` of ``config`` unless it is a non-empty tuple of non-empty strings."""
    value = getattr(config, name)
    if not isinstance(value, tuple) or not value or not all(isinstance(v, str) and v for v in value):
        raise ValueError(f"{name}: expected a non-empty tuple of names, got {value!r}")


def check_path(config: Any, name: str, optional: bool = False) -> None:
    """ValueError naming the field ``name`` of ``config`` unless it is a non-empty path (str or Path; or None, when
    ``optional``)."""
    value = getattr(config, name)
    if optional and value is None:
        return
    if not isinstance(value, (str, Path)) or not str(value):
        raise ValueError(f"{name}: expected a folder path{' or None' if optional else ''}, got {value!r}")


def machine() -> str:
    """'arch, N cores, Python X.Y.Z': the machine line of every report."""
    import os
    import platform

    return f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}"


def best_time(fn, repeats: int) -> float:
    """Seconds of the fastest of ``repeats`` calls (after one warm-up)."""
    fn()
    best = float("inf")
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


def mean_time(fn, repeats: int) -> float:
    """Mean seconds of ``repeats`` calls (after one warm-up)."""
    fn()
    t = time.perf_counter()
    for _ in range(repeats):
        fn()
    return (time.perf_counter() - t) / repeats


def batched(fn, *arrays, batch: int = 8):
    """``fn`` over the arrays' first axis in batches of ``batch``, without autograd; the outputs concatenated
    (torch tensors)."""
    import torch

    with torch.no_grad():
        return torch.cat([fn(*(a[i:i + batch] for a in arrays)) for i in range(0, len(arrays[0]), batch)])


def mean_metrics(pred, gt, mask) -> dict[str, float]:
    """toolkit.metrics.evaluate_batch's metrics (masked protocol) averaged over the batch, as floats."""
    from trioman.toolkit.metrics import evaluate_batch

    m = evaluate_batch(pred, gt, mask)
    return {k: float(v.mean()) for k, v in m.items() if v is not None}


def write_report(out: str | Path, target: str, report: dict, markdown: str) -> Path:
    """Write ``out/target.json`` and ``out/target.md`` (atomic writes); -> the markdown's path."""
    from trioman.runtime.outputs import atomic_write_text

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out / f"{target}.json", json.dumps(report, indent=2) + "\n")
    atomic_write_text(out / f"{target}.md", markdown)
    return out / f"{target}.md"
