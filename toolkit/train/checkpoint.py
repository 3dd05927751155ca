"""Atomic checkpoints live in ``toolkit.loops.checkpoint``, with what every training loop shares. This re-export
stays only for ``bench/ablation.py`` (``condition_check``) until it imports ``latest_checkpoint`` from there;
then this file goes."""

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
