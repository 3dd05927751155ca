"""Refiner model: shapes, numerics, cross-view interaction, validation, backbone registry."""

from __future__ import annotations

import importlib.util

import pytest
import torch

from tests.toolkit.refiner.helpers import open_zero_inits, tiny_config
from trioman.toolkit.refiner import (
    CONDITIONS,
    BackboneUnavailable,
    RefinerConfig,
    create_refiner,
    export_inputs,
    register_backbone,
    registered_backbones,
)
from trioman.toolkit.refiner.config import VIEW_COUNT


def _inputs(batch: int, h: int = 32, w: int = 32, seed: int = 0) -> tuple[torch.Tensor, ...]:
    g = torch.Generator().manual_seed(seed)
    return tuple(torch.rand(batch, 3, h, w, generator=g) for _ in range(3))


@pytest.mark.parametrize("conditions", CONDITIONS)
def test_output_shape_per_conditions(conditions):
    model = create_refiner(tiny_config(conditions=conditions)).eval()
    with torch.no_grad():
        out = model(*_inputs(2, 32, 48))  # non-square, any multiple of total_downsample (4)
    assert out.shape == (2, VIEW_COUNT[conditions], 3, 32, 48)
    assert model.input_names == ("coarse", "reference", "normal")[: VIEW_COUNT[conditions]]
    assert len(export_inputs(model, batch=2)) == VIEW_COUNT[conditions]


def test_default_config_shapes():
    cfg = RefinerConfig()
    assert (cfg.views, cfg.total_downsample, cfg.image_size) == (3, 16, 128)


def test_fresh_refiner_is_the_identity():
    """Zero-initialised decoder outputs + logit residual: outputs = inputs up to the 1e-3 clamp."""
    model = create_refiner(tiny_config()).eval()
    x = _inputs(2)
    with torch.no_grad():
        out = model(*x)
    assert torch.allclose(out, torch.stack(x, dim=1), atol=1.001e-3)


@pytest.mark.parametrize("kind", ["black", "white", "noise", "checker"])
def test_finite_outputs_and_gradients_on_extreme_inputs(kind):
    model = open_zero_inits(create_refiner(tiny_config()))
    shape = (2, 3, 32, 32)
    if kind == "black":
        x = torch.zeros(shape)
    elif kind == "white":
        x = torch.ones(shape)
    elif kind == "noise":
        x = torch.rand(shape, generator=torch.Generator().manual_seed(1))
    else:
        i = torch.arange(32)
        x = ((i[:, None] + i[None, :]) % 2).float().expand(shape).contiguous()
    out = model(x, x, x)
    assert torch.isfinite(out).all() and out.min() >= 0 and out.max() <= 1
    out.square().mean().backward()
    assert all(torch.isfinite(p.grad).all() for p in model.parameters() if p.grad is not None)


@pytest.mark.parametrize("conditions", CONDITIONS)
def test_views_interact_through_attention(conditions):
    model = open_zero_inits(create_refiner(tiny_config(conditions=conditions))).eval()
    coarse, reference, normal = _inputs(2)
    other_ref, other_normal = _inputs(2, seed=5)[:2]
    with torch.no_grad():
        base = model(coarse, reference, normal)[:, 0]
        by_ref = model(coarse, other_ref, normal)[:, 0]
        by_normal = model(coarse, reference, other_normal)[:, 0]
    ref_effect = (base - by_ref).abs().max().item()
    normal_effect = (base - by_normal).abs().max().item()
    if conditions == "none":
        assert ref_effect == 0 and normal_effect == 0
    else:
        assert ref_effect > 1e-4
        assert (normal_effect > 1e-4) == conditions.endswith("+geo")


@pytest.mark.parametrize("conditions", ["warp", "warp+geo"])
def test_warp_refines_the_aligned_reference(conditions):
    """With "warp*" view 0 is the aligned reference (the ``reference`` input): a fresh Refiner returns it
    there and the coarse render as view 1 (the identity, up to the logit clamp)."""
    model = create_refiner(tiny_config(conditions=conditions)).eval()
    coarse, aligned, normal = _inputs(2)
    with torch.no_grad():
        out = model(coarse, aligned, normal)
    assert torch.allclose(out[:, 0], aligned, atol=1.001e-3) and torch.allclose(out[:, 1], coarse, atol=1.001e-3)


def test_batch_items_do_not_interact():
    """Attention groups the V views of one sample: another sample's inputs change nothing."""
    model = open_zero_inits(create_refiner(tiny_config())).eval()
    a = _inputs(3)
    b = tuple(t.clone() for t in a)
    for t in b:
        t[1:] = torch.rand_like(t[1:])
    with torch.no_grad():
        assert torch.allclose(model(*a)[0], model(*b)[0], atol=1e-6)


def test_fused_and_exportable_attention_agree():
    fused = open_zero_inits(create_refiner(tiny_config())).eval()
    plain = create_refiner(tiny_config(), exportable=True).eval()
    plain.load_state_dict(fused.state_dict())
    x = _inputs(2)
    with torch.no_grad():
        assert torch.allclose(fused(*x), plain(*x), atol=1e-5)


def test_create_refiner_is_seeded_and_leaves_global_rng_alone():
    state = torch.get_rng_state()
    a, b, c = (create_refiner(tiny_config(), seed=s) for s in (3, 3, 4))
    assert torch.equal(torch.get_rng_state(), state)
    pa, pb, pc = (torch.cat([p.flatten() for p in m.parameters()]) for m in (a, b, c))
    assert torch.equal(pa, pb) and not torch.equal(pa, pc)


@pytest.mark.parametrize(
    "field, overrides",
    [
        ("image_size", {"image_size": 30}),  # not a multiple of total_downsample 4
        ("latent_channels", {"latent_channels": 0}),
        ("latent_downsample", {"latent_downsample": 3}),
        ("vae_widths", {"vae_widths": (8, 16, 32)}),  # 3 entries for latent_downsample 2
        ("vae_widths", {"vae_widths": (8, 18)}),  # not divisible by norm_groups
        ("unet_widths", {"unet_widths": ()}),
        ("attention_from_level", {"attention_from_level": 3}),
        ("attention_heads", {"attention_heads": 3}),
        ("unet_widths", {"unet_widths": (16, 36), "attention_heads": 8, "attention_from_level": 2}),  # the middle's width
        ("conditions", {"conditions": "geo"}),
        ("residual", {"residual": 1}),
        ("backbone", {"backbone": ""}),
    ],
)
def test_bad_config_values_name_the_field(field, overrides):
    with pytest.raises(ValueError, match=field):
        tiny_config(**overrides)


def test_config_dict_round_trip():
    cfg = tiny_config(conditions="tex")
    assert RefinerConfig.from_dict(cfg.to_dict()) == cfg
    with pytest.raises(ValueError, match="unknown"):
        RefinerConfig.from_dict({**cfg.to_dict(), "depth": 3})


def test_bad_inputs_name_the_argument():
    model = create_refiner(tiny_config()).eval()
    c, r, n = _inputs(1)
    with pytest.raises(ValueError, match="reference: required"):
        model(c)
    with pytest.raises(ValueError, match="normal: required"):
        model(c, r)
    with pytest.raises(ValueError, match="coarse: expected shape"):
        model(c[:, :1], r, n)
    with pytest.raises(ValueError, match="coarse: H and W must be positive multiples of 4"):
        model(c[..., :30], r[..., :30], n[..., :30])
    with pytest.raises(ValueError, match="reference: shape"):
        model(c, r[..., :16, :16], n)
    with pytest.raises(TypeError, match="coarse"):
        model(c.to(torch.uint8), r, n)


def test_backbone_registry():
    assert {"scratch", "sd-turbo"} <= set(registered_backbones())
    with pytest.raises(ValueError, match="backbone: unknown 'nope'"):
        create_refiner(tiny_config(backbone="nope"))
    with pytest.raises(ValueError, match="already registered"):
        register_backbone("scratch")(lambda config, exportable: None)


def test_sd_turbo_without_diffusers_names_the_extra(monkeypatch):
    find_spec = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "diffusers" else find_spec(name, *a))
    with pytest.raises(BackboneUnavailable, match=r"trioman\[diffusion\]"):
        create_refiner(tiny_config(backbone="sd-turbo", pretrained_path="/nowhere"))
