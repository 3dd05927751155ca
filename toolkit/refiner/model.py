"""The Refiner (paper 3.2.5): a one-step, Difix-like multi-view latent U-Net trained from scratch (``Refiner``).

Its views, conditions and output activation: docs/design.md, "Refiner (3.2.5, Difix-like)".
"""

from __future__ import annotations

import torch
from torch import nn

from trioman.toolkit.refiner.autoencoder import Decoder, Encoder
from trioman.toolkit.refiner.config import ALIGNED_CONDITIONS, VIEW_COUNT, RefinerConfig
from trioman.toolkit.refiner.unet import ViewUNet

INPUT_NAMES = ("coarse", "reference", "normal")  # the forward arguments, in view order
OUTPUT_NAME = "refined"
LOGIT_EPS = 1e-3


def check_refiner_inputs(input_names: tuple[str, ...], conditions: str, downsample: int, what: str,
                         coarse: torch.Tensor, reference: torch.Tensor | None, normal: torch.Tensor | None) -> None:
    """The inputs a Refiner backbone reads: float [B, 3, H, W], H and W positive multiples of ``downsample``
    (``what`` names it in the message), all shaped like ``coarse``; else ValueError/TypeError naming the argument."""
    for name, x in zip(INPUT_NAMES, (coarse, reference, normal)):
        if name not in input_names:
            continue
        if x is None:
            raise ValueError(f"{name}: required with conditions={conditions!r}")
        if not isinstance(x, torch.Tensor) or not x.is_floating_point():
            raise TypeError(f"{name}: expected a float torch.Tensor [B, 3, H, W] in [0, 1], got {type(x).__name__}")
        if x.ndim != 4 or x.shape[1] != 3 or x.shape[0] < 1:
            raise ValueError(f"{name}: expected shape [B, 3, H, W], got {tuple(x.shape)}")
        if x.shape[2] % downsample or x.shape[3] % downsample or x.shape[2] == 0 or x.shape[3] == 0:
            raise ValueError(f"{name}: H and W must be positive multiples of {downsample} ({what}), got {tuple(x.shape[2:])}")
        if x.shape != coarse.shape:
            raise ValueError(f"{name}: shape {tuple(x.shape)} differs from coarse {tuple(coarse.shape)}")


def view_images(conditions: str, coarse: torch.Tensor, reference: torch.Tensor | None,
                normal: torch.Tensor | None) -> list[torch.Tensor]:
    """The V images the views encode, in view order; view 0's output is the refined frame.

    "none" / "tex" / "tex+geo": (coarse[, reference[, normal]]), the paper's. "warp" / "warp+geo": ``reference``
    is the geometry-aligned reference filled with the coarse render where no real pixel was carried, and the
    views are (reference, coarse[, normal]): the Refiner refines the aligned image, and the coarse view
    tells it where the two agree (nothing carried there) and where the carried pixels disagree with the render.
    """
    images = [coarse, reference, normal]
    if conditions in ALIGNED_CONDITIONS:
        images[:2] = [reference, coarse]
    return images[: VIEW_COUNT[conditions]]


class Refiner(nn.Module):
    """``forward(coarse, reference=None, normal=None)`` with [B, 3, H, W] images in [0, 1] -> [B, V, 3, H, W].

    H and W must be multiples of ``config.total_downsample``. ``reference`` (I^{T+k}) is required when
    ``conditions`` includes "tex", ``normal`` (I_g^T) when it is "tex+geo"; inputs the conditions do not
    use are ignored, so one batch feeds every ablation. ``exportable`` writes attention as plain
    matmul/softmax (ONNX); otherwise it uses ``scaled_dot_product_attention``.
    """

    def __init__(self, config: RefinerConfig, exportable: bool = False) -> None:
        super().__init__()
        self.config = config
        self.views = config.views
        self.tex_views = min(config.views, 2)  # views through E_t / D_t: coarse (+ reference)
        c = config
        self.tex_encoder = Encoder(c.vae_widths, c.latent_channels, c.norm_groups)
        self.tex_decoder = Decoder(c.vae_widths, c.latent_channels, c.norm_groups)
        if self.views == 3:
            self.geo_encoder = Encoder(c.vae_widths, c.latent_channels, c.norm_groups)
            self.geo_decoder = Decoder(c.vae_widths, c.latent_channels, c.norm_groups)
        self.unet = ViewUNet(
            c.latent_channels, c.unet_widths, c.views, c.attention_heads, c.norm_groups, c.attention_from_level, not exportable
        )

    @property
    def input_names(self) -> tuple[str, ...]:
        return INPUT_NAMES[: self.views]

    @property
    def total_downsample(self) -> int:
        """H and W must be multiples of this (the config's; every backbone's model has the attribute)."""
        return self.config.total_downsample

    def check_inputs(self, coarse: torch.Tensor, reference: torch.Tensor | None, normal: torch.Tensor | None) -> None:
        """Raise ValueError/TypeError naming the argument for a missing or misshapen input."""
        check_refiner_inputs(self.input_names, self.config.conditions, self.config.total_downsample, "total downsampling",
                             coarse, reference, normal)

    def forward(self, coarse: torch.Tensor, reference: torch.Tensor | None = None, normal: torch.Tensor | None = None) -> torch.Tensor:
        if not torch.jit.is_tracing():
            self.check_inputs(coarse, reference, normal)
        H, W = coarse.shape[2], coarse.shape[3]
        v, vt = self.views, self.tex_views
        images = view_images(self.config.conditions, coarse, reference, normal)
        tex = torch.cat(images[:vt])  # [(vt B), 3, H, W], view-major
        z_tex, skips_tex = self.tex_encoder(tex)
        c, h, w = z_tex.shape[1], z_tex.shape[2], z_tex.shape[3]
        z = z_tex.reshape(vt, -1, c, h, w)  # [vt, B, c, h, w]
        if v == 3:
            z_geo, skips_geo = self.geo_encoder(normal)
            z = torch.cat([z, z_geo[None]])
        z = self.unet(z.transpose(0, 1).reshape(-1, c, h, w))  # (b v) order in and out
        z = z.reshape(-1, v, c, h, w).transpose(0, 1)  # [V, B, c, h, w]
        logits = self.tex_decoder(z[:vt].reshape(-1, c, h, w), skips_tex)  # [(vt B), 3, H, W]
        if v == 3:
            logits = torch.cat([logits, self.geo_decoder(z[2], skips_geo)])
        if self.config.residual:
            x = torch.cat(images).clamp(LOGIT_EPS, 1.0 - LOGIT_EPS)
            logits = logits + torch.log(x) - torch.log(1.0 - x)
        return torch.sigmoid(logits).reshape(v, -1, 3, H, W).transpose(0, 1)


def export_inputs(config: RefinerConfig | Refiner, batch: int = 2, seed: int = 0) -> tuple[torch.Tensor, ...]:
    """Example inputs (coarse[, reference[, normal]]) [batch, 3, S, S] in [0, 1], S = image_size, one per
    input the conditions use (trace with batch >= 2; see ``INPUT_NAMES`` / ``Refiner.input_names``)."""
    if isinstance(config, Refiner):
        config = config.config
    if not isinstance(batch, int) or batch < 1:
        raise ValueError(f"batch: must be a positive integer, got {batch!r}")
    g = torch.Generator().manual_seed(seed)
    shape = (batch, 3, config.image_size, config.image_size)
    return tuple(torch.rand(shape, generator=g) for _ in range(config.views))
