"""The model to export: an exportable copy of a Refiner or Examiner, from a module or a checkpoint."""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path
from typing import Any, NamedTuple

import torch
from torch import nn

from trioman.export.onnx_models.errors import ExportError


def resolve_checkpoint(ckpt: str | os.PathLike) -> Path:
    """A checkpoint file itself, or a run folder's model checkpoint (its validation-selected
    weights, run/selected.pt, if it has them, else its latest checkpoint)."""
    from trioman.toolkit.loops.checkpoint import model_checkpoint

    path = Path(ckpt)
    if path.is_dir():
        found = model_checkpoint(path)
        if found is None:
            raise FileNotFoundError(f"{path}: run folder without a checkpoint (no checkpoints/ckpt_*.pt)")
        return found
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such checkpoint file or run folder")
    return path


def config_hash(model_config: dict, train_config: dict | None) -> str:
    """sha256 hex of {"model": model config, "train": training config} as JSON with sorted keys."""
    text = json.dumps({"model": model_config, "train": train_config}, sort_keys=True, default=str)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


class _CenteredGroupNorm(nn.GroupNorm):
    """GroupNorm that subtracts each group's mean before normalising: the same function, but exported as
    ReduceMean + Sub before ONNX InstanceNormalization, whose onnxruntime CPU kernel computes the variance
    in one pass (E[x^2] - E[x]^2) and loses precision when a group's mean is large against its spread
    (docs/findings.md, "ONNX export")."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        g = x.reshape(x.shape[0], self.num_groups, -1)
        x = (g - g.mean(dim=-1, keepdim=True)).reshape(x.shape)
        return nn.functional.group_norm(x, self.num_groups, self.weight, self.bias, self.eps)


def _center_group_norms(model: nn.Module) -> nn.Module:
    for m in model.modules():
        if type(m) is nn.GroupNorm:
            m.__class__ = _CenteredGroupNorm
    return model


class Source(NamedTuple):
    model: nn.Module  # exportable, eval mode
    source: str
    step: int | None
    config_hash: str


def load_source(kind: str, model_or_ckpt: Any) -> Source:
    """An exportable copy of the model (or the checkpoint's model) and where it came from."""
    from trioman.toolkit.examiner import Examiner, ExaminerConfig
    from trioman.toolkit.refiner import RefinerConfig, create_refiner

    def build(config: Any) -> nn.Module:
        with torch.random.fork_rng(devices=[]):  # initial weights are overwritten; keep the global RNG
            if kind == "refiner":
                return _center_group_norms(create_refiner(config, exportable=True, seed=0))
            return Examiner(config, exportable=True)

    if isinstance(model_or_ckpt, nn.Module):
        config = getattr(model_or_ckpt, "config", None)
        want = RefinerConfig if kind == "refiner" else ExaminerConfig
        if not isinstance(config, want):
            raise ExportError(f"{kind}: expected a {kind.capitalize()} module (with a {want.__name__} .config), "
                              f"got {type(model_or_ckpt).__name__}")
        model = build(config)
        model.load_state_dict(model_or_ckpt.state_dict())
        return Source(model.eval(), f"<in-memory {type(model_or_ckpt).__name__}>", None, config_hash(config.to_dict(), None))
    from trioman.toolkit.loops.checkpoint import load_checkpoint

    path = resolve_checkpoint(model_or_ckpt)
    state = load_checkpoint(path)
    try:
        config = (RefinerConfig if kind == "refiner" else ExaminerConfig).from_dict(state["config"])
    except (TypeError, ValueError) as err:
        raise ExportError(f"{path}: not a {kind} checkpoint ({err})") from None
    model = build(config)
    try:
        model.load_state_dict(state["model"])
    except RuntimeError as err:
        raise ExportError(f"{path}: weights do not fit a {kind} of its config ({str(err).splitlines()[0]})") from None
    return Source(model.eval(), str(path.resolve()), int(state["step"]), config_hash(state["config"], state.get("train")))
