"""Tiny Refiner configs and a synthetic restoration task for the tests."""

from __future__ import annotations

import torch
import torch.nn.functional as F

from trioman.toolkit.refiner import RefinerBatch, RefinerConfig


def tiny_config(**overrides) -> RefinerConfig:
    """32x32 images, 2x latents, a 2-level U-Net: total downsampling 4."""
    base = dict(
        image_size=32,
        latent_channels=4,
        latent_downsample=2,
        vae_widths=(8, 16),
        unet_widths=(16, 32),
        attention_from_level=1,
        attention_heads=2,
        norm_groups=4,
    )
    return RefinerConfig(**{**base, **overrides})


def smooth_texture(batch: int, size: int, g: torch.Generator) -> torch.Tensor:
    """Random smooth colour texture [batch, 3, size, size] in [0, 1] (bilinear upsampling of 8x8 noise)."""
    low = torch.rand(batch, 3, 8, 8, generator=g)
    return F.interpolate(low, size=(size, size), mode="bilinear", align_corners=False)


def synthetic_batch(step: int, batch: int = 4, size: int = 32) -> RefinerBatch:
    """Restoration task: coarse = washed-out, noisy target; reference = the target shifted by 2 pixels
    (a stand-in for I^{T+k}); normal = another smooth texture. Deterministic in ``step``."""
    g = torch.Generator().manual_seed(1000 + step)
    target = smooth_texture(batch, size, g)
    coarse = (0.25 + 0.5 * target + 0.05 * torch.randn(target.shape, generator=g)).clamp(0.0, 1.0)
    reference = torch.roll(target, shifts=(2, 2), dims=(2, 3))
    normal = smooth_texture(batch, size, g)
    return RefinerBatch(coarse, reference, normal, target, reference)


def open_zero_inits(model: torch.nn.Module, std: float = 0.05, seed: int = 0) -> torch.nn.Module:
    """Fill the zero-initialised parameters (decoder output convs, skip convs) with small noise, so an
    untrained model is no longer the identity and views can be seen to interact."""
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for p in model.parameters():
            if not p.any():
                p.copy_(torch.randn(p.shape, generator=g) * std)
    return model
