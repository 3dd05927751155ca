"""The latent U-Net whose self-attention spans all views of a sample (paper 3.2.5, Difix mv_unet)."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from trioman.toolkit.refiner.blocks import Downsample, ResBlock, Upsample, ViewAttention, conv3x3


class _Level(nn.Module):
    """A ResBlock, followed by cross-view attention when ``attention``."""

    def __init__(self, c_in: int, c_out: int, views: int, heads: int, groups: int, attention: bool, fused: bool) -> None:
        super().__init__()
        self.res = ResBlock(c_in, c_out, groups)
        self.attn = ViewAttention(c_out, views, heads, groups, fused) if attention else nn.Identity()

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.attn(self.res(x))


class ViewUNet(nn.Module):
    """Latents [B * V, c, h, w] in (b v) order -> refined latents [B * V, c, h, w], in one step.

    Level i (0 = latent resolution) runs at 1 / 2**i with ``widths[i]`` channels; levels >=
    ``attention_from`` and the middle add :class:`ViewAttention` across the V views; the up path
    concatenates each level's down output. A learned per-view role embedding (coarse, texture,
    geometry) is added after the input conv, so attention can tell the views apart. One step: there
    is no timestep input; Difix's fixed timestep would be a constant embedding, i.e. a constant bias
    that the learned role embedding and conv biases already absorb. Output: z + U(z), a residual on
    the latent (Difix's x0 = (z - sqrt(1 - a) eps) / sqrt(a) is likewise affine in z and the net output).
    """

    def __init__(
        self,
        latent_channels: int,
        widths: tuple[int, ...],
        views: int,
        heads: int,
        groups: int,
        attention_from: int,
        fused: bool,
    ) -> None:
        super().__init__()
        levels = len(widths)
        self.views = views
        self.conv_in = conv3x3(latent_channels, widths[0])
        self.view_embed = nn.Parameter(torch.randn(views, widths[0]) * 0.02)  # [V, widths[0]]
        self.down = nn.ModuleList(
            _Level(widths[i], widths[i], views, heads, groups, i >= attention_from, fused) for i in range(levels)
        )
        self.downsample = nn.ModuleList(Downsample(widths[i], widths[i + 1]) for i in range(levels - 1))
        self.mid = nn.Sequential(
            ResBlock(widths[-1], widths[-1], groups),
            ViewAttention(widths[-1], views, heads, groups, fused),
            ResBlock(widths[-1], widths[-1], groups),
        )
        self.up = nn.ModuleList(
            _Level(2 * widths[i], widths[i], views, heads, groups, i >= attention_from, fused) for i in range(levels)
        )
        self.upsample = nn.ModuleList(Upsample(widths[i + 1], widths[i]) for i in range(levels - 1))
        self.norm_out = nn.GroupNorm(groups, widths[0])
        self.conv_out = conv3x3(widths[0], latent_channels)

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        _, _, h, w = z.shape
        x = self.conv_in(z)
        c = x.shape[1]
        x = (x.reshape(-1, self.views, c, h, w) + self.view_embed[None, :, :, None, None]).reshape(-1, c, h, w)
        skips = []
        for i, level in enumerate(self.down):
            x = level(x)
            skips.append(x)
            if i < len(self.downsample):
                x = self.downsample[i](x)
        x = self.mid(x)
        for i in reversed(range(len(self.up))):
            x = self.up[i](torch.cat([x, skips[i]], dim=1))
            if i > 0:
                x = self.upsample[i - 1](x)
        return z + self.conv_out(F.silu(self.norm_out(x)))
