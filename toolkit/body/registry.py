"""Body models by name (timm-style registry)."""

from __future__ import annotations

from typing import Callable

from trioman.toolkit.body.base import BodyModel

_REGISTRY: dict[str, Callable[..., BodyModel]] = {}


def register_body_model(name: str):
    def deco(factory: Callable[..., BodyModel]) -> Callable[..., BodyModel]:
        _REGISTRY[name] = factory
        return factory

    return deco


@register_body_model("anny")
def _anny(**kwargs) -> BodyModel:
    from trioman.toolkit.body.anny_model import AnnyBody

    return AnnyBody(**kwargs)


@register_body_model("smplx")
def _smplx(**kwargs) -> BodyModel:
    from trioman.toolkit.body.smplx_model import SMPLXBody

    return SMPLXBody(**kwargs)


def list_body_models() -> list[str]:
    return sorted(_REGISTRY)


def create_body_model(name: str = "anny", **kwargs) -> BodyModel:
    """Create a body model by name, e.g. create_body_model("anny", phenotype={"height": 0.7})."""
    if name not in _REGISTRY:
        raise ValueError(f"body_model: unknown body model {name!r}; available: {list_body_models()}")
    return _REGISTRY[name](**kwargs)
