"""Atomic checkpoints: written to a temporary sibling and renamed, so a kill at any moment loses
no finished checkpoint. Loaded with weights_only=True (data, never code)."""

from __future__ import annotations

import io
import os
import re
from pathlib import Path
from typing import Any

import torch

from trioman.runtime.outputs import FolderKind, atomic_write_bytes

_NAME = re.compile(r"ckpt_(\d{7})\.pt")  # fullmatch
SELECTED = "selected.pt"  # run/selected.pt: weights chosen by validation (checkpoint format, no optimizer)
CHECKPOINTS = "checkpoints"  # run/checkpoints/ckpt_<step>.pt
# A training loop's own run (toolkit/loops: the Refiner's, the Examiner's), what a fresh start may remove
LOOP_RUN = FolderKind("training loop", CHECKPOINTS, files=(SELECTED,), folders=((CHECKPOINTS, ("ckpt_*.pt",)),))


class ConfigMismatch(ValueError):
    """A run's checkpoint holds a model of another config than the one asked to resume it.

    ``run_config`` and ``config``: the two configs (dicts); ``differences``: {field: (the run's value, this
    one's)} of the fields that differ, and nothing else; ``hint``: what would resume the run (the command,
    which only the caller knows), else a generic sentence. The message is one line naming the fields."""

    def __init__(self, checkpoint: str | os.PathLike, what: str, run_config: dict[str, Any], config: dict[str, Any],
                 hint: str | None = None) -> None:
        self.checkpoint, self.what, self.hint = Path(checkpoint), what, hint
        self.run_config, self.config = dict(run_config), dict(config)
        self.differences = config_differences(self.run_config, self.config)
        fields = ", ".join(f"{name}: {_shown(a)} -> {_shown(b)}" for name, (a, b) in self.differences.items())
        tail = hint or "resume it with the options it was started with, or choose another run folder"
        super().__init__(f"{checkpoint}: the run's {what} differs from this one ({fields}); {tail}")

    def with_hint(self, hint: str) -> "ConfigMismatch":
        return ConfigMismatch(self.checkpoint, self.what, self.run_config, self.config, hint)


class _Absent:
    def __repr__(self) -> str:
        return "(absent)"


ABSENT = _Absent()  # a field one of two configs lacks (config_differences)


def _shown(value: Any) -> str:
    return repr(value) if isinstance(value, str) or value is None else str(value)


def config_differences(run_config: dict[str, Any], config: dict[str, Any]) -> dict[str, tuple[Any, Any]]:
    """{field: (run_config's value, config's)} of the fields whose values differ (ABSENT where one lacks it)."""
    names = [*config, *(name for name in run_config if name not in config)]
    return {name: (run_config.get(name, ABSENT), config.get(name, ABSENT)) for name in names
            if name not in run_config or name not in config or run_config[name] != config[name]}


def check_config(checkpoint: str | os.PathLike, run_config: dict[str, Any], config: dict[str, Any], what: str) -> None:
    """Raise ConfigMismatch naming the fields in which the run's model config differs from ``config``."""
    if run_config != config:
        raise ConfigMismatch(checkpoint, what, run_config, config)


def checkpoint_path(run: Path, step: int) -> Path:
    return Path(run) / CHECKPOINTS / f"ckpt_{step:07d}.pt"


def save_atomic(path: Path, state: dict[str, Any]) -> None:
    """``torch.save(state)`` to ``path`` atomically, serialised in memory first: a full disk or a read-only
    folder is then an OSError naming ``path`` (torch.save to a file reports it as "unexpected pos")."""
    buf = io.BytesIO()
    torch.save(state, buf)
    atomic_write_bytes(path, buf.getvalue())


def save_checkpoint(run: Path, step: int, state: dict[str, Any], keep: int = 2) -> Path:
    """Write ``state`` for ``step`` and keep only the newest ``keep`` checkpoints."""
    path = checkpoint_path(run, step)
    path.parent.mkdir(parents=True, exist_ok=True)
    save_atomic(path, state)
    for old in list_checkpoints(run)[:-keep]:
        old.unlink(missing_ok=True)
    return path


def list_checkpoints(run: Path) -> list[Path]:
    """Finished checkpoints, oldest first (temporary files are ignored)."""
    folder = Path(run) / CHECKPOINTS
    if not folder.is_dir():
        return []
    return sorted(p for p in folder.iterdir() if _NAME.fullmatch(p.name))


def load_checkpoint(path: str | os.PathLike) -> dict[str, Any]:
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such checkpoint")
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:  # corrupt, truncated, or not a checkpoint at all
        raise ValueError(f"{path}: not a readable checkpoint ({type(err).__name__}: {err})") from None
    for key in ("step", "model", "config"):
        if key not in state:
            raise ValueError(f"{path}: checkpoint has no {key!r} entry")
    return state


def latest_checkpoint(run: Path) -> Path | None:
    found = list_checkpoints(run)
    return found[-1] if found else None


def model_checkpoint(run: Path) -> Path | None:
    """The checkpoint whose weights a run folder's model uses: run/selected.pt (the step chosen by
    validation, ``examiner_loop(validate=...)``) when present, else the latest checkpoint."""
    selected = Path(run) / SELECTED
    return selected if selected.is_file() else latest_checkpoint(run)
