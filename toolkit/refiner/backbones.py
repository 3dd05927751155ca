"""Backbone registry: ``create_refiner`` builds the model named by ``RefinerConfig.backbone``.

"scratch" is the from-scratch :class:`Refiner`. "sd-turbo" is the paper's pretrained backbone (SD-Turbo
VAE + U-Net, as in Difix; :mod:`trioman.toolkit.refiner.sd_turbo`), built from a local folder in diffusers
layout (``RefinerConfig.pretrained_path``; nothing is ever downloaded) with the optional diffusers package
(``trioman[diffusion]``).
"""

from __future__ import annotations

import dataclasses
import importlib.util
from typing import Any, Callable

import torch
from torch import nn

from trioman.toolkit.refiner.config import RefinerConfig
from trioman.toolkit.refiner.model import Refiner

# (config, exportable) -> a module with ``.config`` and the forward of Refiner (coarse, reference, normal) -> [B, V, 3, H, W]
BackboneFactory = Callable[[RefinerConfig, bool], nn.Module]
_BACKBONES: dict[str, BackboneFactory] = {}


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
    if importlib.util.find_spec("diffusers") is None:
        raise BackboneUnavailable("backbone 'sd-turbo' needs the diffusers package: pip install 'trioman[diffusion]'")
    from trioman.toolkit.refiner.sd_turbo import SdTurboRefiner

    return SdTurboRefiner(config, exportable=exportable)
