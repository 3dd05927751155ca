"""Image encoders and decoders of the Refiner (the roles of the SD-Turbo VAE in Difix).

The encoder is deterministic (Difix samples ``latent_dist``; the mean is what an export wants) and
hands its per-resolution features to the decoder of the same modality, pix2pix-turbo style: each
skip passes through a 1x1 conv without bias, zero-initialised, added before the decoder block of that
resolution, so detail can bypass the latent bottleneck once the skips have learned to open.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from trioman.toolkit.refiner.blocks import Downsample, ResBlock, Upsample, conv3x3


class Encoder(nn.Module):
    """Image [N, 3, H, W] in [0, 1] -> (latent [N, c, H / f, W / f], skips), f = 2 ** (len(widths) - 1).

    skips[i] is the feature map [N, widths[i], H / 2**i, W / 2**i] entering the i-th downsampling.
    """

    def __init__(self, widths: tuple[int, ...], latent_channels: int, groups: int) -> None:
        super().__init__()
        self.conv_in = conv3x3(3, widths[0])
        self.blocks = nn.ModuleList(ResBlock(widths[i], widths[i], groups) for i in range(len(widths) - 1))
        self.downs = nn.ModuleList(Downsample(widths[i], widths[i + 1]) for i in range(len(widths) - 1))
        self.mid = ResBlock(widths[-1], widths[-1], groups)
        self.norm_out = nn.GroupNorm(groups, widths[-1])
        self.conv_out = conv3x3(widths[-1], latent_channels)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, list[torch.Tensor]]:
        h = self.conv_in(x * 2.0 - 1.0)
        skips = []
        for block, down in zip(self.blocks, self.downs):
            h = block(h)
            skips.append(h)
            h = down(h)
        h = self.mid(h)
        return self.conv_out(F.silu(self.norm_out(h))), skips


class Decoder(nn.Module):
    """(latent [N, c, h, w], encoder skips) -> logits [N, 3, h * f, w * f], f = 2 ** (len(widths) - 1).

    The output conv is zero-initialised: a fresh decoder returns zeros, which the Refiner turns into
    the identity (residual mode) or mid-grey.
    """

    def __init__(self, widths: tuple[int, ...], latent_channels: int, groups: int) -> None:
        super().__init__()
        stages = len(widths) - 1
        self.conv_in = conv3x3(latent_channels, widths[-1])
        self.mid = ResBlock(widths[-1], widths[-1], groups)
        # index i works at resolution 1 / 2**i, run from the coarsest (i = stages - 1) up
        self.ups = nn.ModuleList(Upsample(widths[i + 1], widths[i]) for i in range(stages))
        self.skip_convs = nn.ModuleList(nn.Conv2d(widths[i], widths[i], 1, bias=False) for i in range(stages))
        self.blocks = nn.ModuleList(ResBlock(widths[i], widths[i], groups) for i in range(stages))
        self.norm_out = nn.GroupNorm(groups, widths[0])
        self.conv_out = conv3x3(widths[0], 3)
        for conv in self.skip_convs:
            nn.init.zeros_(conv.weight)
        nn.init.zeros_(self.conv_out.weight)
        nn.init.zeros_(self.conv_out.bias)

    def forward(self, z: torch.Tensor, skips: list[torch.Tensor]) -> torch.Tensor:
        h = self.mid(self.conv_in(z))
        for i in reversed(range(len(self.ups))):
            h = self.ups[i](h) + self.skip_convs[i](skips[i])
            h = self.blocks[i](h)
        return self.conv_out(F.silu(self.norm_out(h)))
