"""Atomic checkpoints live in ``toolkit.loops.checkpoint``, with what every training loop shares; these names
stay importable here for the avatar loop and the callers outside toolkit until they import them from there."""

from trioman.toolkit.loops.checkpoint import (
    ConfigMismatch,
    checkpoint_path,
    latest_checkpoint,
    list_checkpoints,
    load_checkpoint,
    model_checkpoint,
    save_checkpoint,
)

__all__ = ["ConfigMismatch", "checkpoint_path", "latest_checkpoint", "list_checkpoints", "load_checkpoint",
           "model_checkpoint", "save_checkpoint"]
