"""Backbone registry: ``create_refiner`` builds the model named by ``RefinerConfig.backbone``.

"scratch" is the from-scratch :class:`Refiner`. "sd-turbo" is the extension point for the paper's
pretrained backbone (SD-Turbo VAE + U-Net, as in Difix; docs/design.md, "Refiner"): it checks what such a
build needs (the diffusers package and a local SD-Turbo folder in diffusers layout; nothing is ever
downloaded) and says what is missing; the adapter itself is not written yet.
"""

from __future__ import annotations

import dataclasses
import importlib.util
from pathlib import Path
from typing import Any, Callable

import torch
from torch import nn

from trioman.toolkit.refiner.config import RefinerConfig
from trioman.toolkit.refiner.model import Refiner

# (config, exportable) -> a module with ``.config`` and the forward of Refiner (coarse, reference, normal) -> [B, V, 3, H, W]
BackboneFactory = Callable[[RefinerConfig, bool], nn.Module]
_BACKBONES: dict[str, BackboneFactory] = {}
SD_TURBO_PARTS = ("model_index.json", "vae", "unet", "scheduler", "tokenizer", "text_encoder")


class BackboneUnavailable(RuntimeError):
    """A registered backbone cannot be built here (a package or local weights are missing)."""


def register_backbone(name: str) -> Callable[[BackboneFactory], BackboneFactory]:
    """Decorator registering ``factory(config, exportable) -> nn.Module`` under ``name``."""

    def decorate(factory: BackboneFactory) -> BackboneFactory:
        if name in _BACKBONES:
            raise ValueError(f"backbone: {name!r} is already registered")
        _BACKBONES[name] = factory
        return factory

    return decorate


def registered_backbones() -> tuple[str, ...]:
    return tuple(sorted(_BACKBONES))


def create_refiner(
    config: RefinerConfig | None = None, *, exportable: bool = False, seed: int | None = 0, **overrides: Any
) -> nn.Module:
    """The Refiner for ``config`` (with ``overrides``), parameters initialised from ``seed`` without
    touching the global RNG (None: from the global RNG)."""
    config = dataclasses.replace(config or RefinerConfig(), **overrides)
    factory = _BACKBONES.get(config.backbone)
    if factory is None:
        raise ValueError(f"backbone: unknown {config.backbone!r}, registered: {list(registered_backbones())}")
    if seed is None:
        return factory(config, exportable)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        return factory(config, exportable)


@register_backbone("scratch")
def _scratch(config: RefinerConfig, exportable: bool) -> nn.Module:
    return Refiner(config, exportable=exportable)


@register_backbone("sd-turbo")
def _sd_turbo(config: RefinerConfig, exportable: bool) -> nn.Module:
    missing = []
    if importlib.util.find_spec("diffusers") is None:
        missing.append("the diffusers package (pip install diffusers)")
    if config.pretrained_path is None:
        missing.append("pretrained_path: a local SD-Turbo folder in diffusers layout (stabilityai/sd-turbo)")
    else:
        root = Path(config.pretrained_path)
        if not root.is_dir():
            missing.append(f"pretrained_path: {root} is not a folder")
        else:
            missing += [f"{root / part}" for part in SD_TURBO_PARTS if not (root / part).exists()]
    if missing:
        raise BackboneUnavailable("backbone 'sd-turbo' needs, and this machine lacks: " + "; ".join(missing) + ". Nothing is downloaded.")
    raise NotImplementedError(
        "backbone 'sd-turbo': the adapter is not written yet. It would load AutoencoderKL (vae/) as E_t, E_g,"
        " D_t, D_g with 1x1 skip convs (pix2pix-turbo), the UNet2DConditionModel (unet/) with its self-attention"
        " wrapped to span the views, a precomputed 'remove degradation' prompt embedding, and one DDPM step at"
        " a fixed timestep, in place of this factory."
    )
