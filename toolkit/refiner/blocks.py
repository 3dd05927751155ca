"""Building blocks of the Refiner: residual conv blocks, resampling, and cross-view self-attention.

Every block takes NCHW feature maps whose batch axis holds B * V views in (b v) order; convs and
GroupNorm therefore act on each view alone, and only :class:`ViewAttention` mixes the views.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn


def conv3x3(c_in: int, c_out: int, stride: int = 1) -> nn.Conv2d:
    return nn.Conv2d(c_in, c_out, 3, stride=stride, padding=1)


class ResBlock(nn.Module):
    """GroupNorm-SiLU-conv twice plus a (1x1 when widths differ) shortcut: [N, c_in, h, w] -> [N, c_out, h, w]."""

    def __init__(self, c_in: int, c_out: int, groups: int) -> None:
        super().__init__()
        self.norm1 = nn.GroupNorm(groups, c_in)
        self.conv1 = conv3x3(c_in, c_out)
        self.norm2 = nn.GroupNorm(groups, c_out)
        self.conv2 = conv3x3(c_out, c_out)
        self.shortcut = nn.Conv2d(c_in, c_out, 1) if c_in != c_out else nn.Identity()

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        h = self.conv1(F.silu(self.norm1(x)))
        h = self.conv2(F.silu(self.norm2(h)))
        return self.shortcut(x) + h


class Downsample(nn.Module):
    """Stride-2 3x3 conv: [N, c_in, h, w] -> [N, c_out, h / 2, w / 2] (h, w even)."""

    def __init__(self, c_in: int, c_out: int) -> None:
        super().__init__()
        self.conv = conv3x3(c_in, c_out, stride=2)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.conv(x)


class Upsample(nn.Module):
    """Nearest x2 (no antialiasing, exports as one Resize) then a 3x3 conv: [N, c_in, h, w] -> [N, c_out, 2h, 2w]."""

    def __init__(self, c_in: int, c_out: int) -> None:
        super().__init__()
        self.conv = conv3x3(c_in, c_out)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.conv(F.interpolate(x, scale_factor=2.0, mode="nearest"))


class ViewAttention(nn.Module):
    """Pre-norm multi-head self-attention across the V views of each sample (Difix's mv_unet trick).

    x [B * V, C, h, w] in (b v) order -> tokens [B, V * h * w, C], so every token of every view attends
    to every token of all V views; the result is added back to x ([B * V, C, h, w]). V is fixed at
    construction (no global patching, any V >= 1). There is no positional encoding: the convs around
    the block supply local position, and matching across views is by content. ``fused`` uses
    ``F.scaled_dot_product_attention``; otherwise plain matmul/softmax with q pre-scaled (ONNX export).
    """

    def __init__(self, channels: int, views: int, heads: int, groups: int, fused: bool) -> None:
        super().__init__()
        if channels % heads:
            raise ValueError(f"channels: {channels} is not divisible by heads {heads}")
        self.views = views
        self.heads = heads
        self.fused = fused
        self.scale = (channels // heads) ** -0.5
        self.norm = nn.GroupNorm(groups, channels)
        self.qkv = nn.Linear(channels, 3 * channels)
        self.proj = nn.Linear(channels, channels)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        _, c, h, w = x.shape
        n = self.views * h * w
        t = self.norm(x).flatten(2).transpose(1, 2).reshape(-1, n, c)  # [B, V*h*w, C]
        qkv = self.qkv(t).reshape(-1, n, 3, self.heads, c // self.heads).permute(2, 0, 3, 1, 4)
        q, k, v = qkv[0], qkv[1], qkv[2]  # [B, heads, V*h*w, C / heads]
        if self.fused:
            o = F.scaled_dot_product_attention(q, k, v)
        else:
            o = ((q * self.scale) @ k.transpose(-2, -1)).softmax(dim=-1) @ v
        o = self.proj(o.transpose(1, 2).reshape(-1, n, c))  # [B, V*h*w, C]
        return x + o.reshape(-1, h * w, c).transpose(1, 2).reshape(-1, c, h, w)
