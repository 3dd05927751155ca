"""What every training loop's config checks the same way, standard-library only (configs are read without torch)."""

from __future__ import annotations

from typing import Any


def check_loop_settings(cfg: Any) -> None:
    """Raise ValueError naming the field when a training loop's config has ``checkpoint_every``,
    ``keep_checkpoints`` or ``max_skipped`` (consecutive non-finite steps that stop the run) that is not a
    positive integer."""
    for name in ("checkpoint_every", "keep_checkpoints", "max_skipped"):
        v = getattr(cfg, name)
        if isinstance(v, bool) or not isinstance(v, int) or v < 1:
            raise ValueError(f"{name}: must be a positive integer, got {v!r}")
