"""A plain Vision Transformer in timm's style, the Examiner's backbone V.

Parameter names follow timm's ``VisionTransformer`` (class token, no register tokens, no layer
scale, ``global_pool='token'``, ``num_classes=0``): ``cls_token``, ``pos_embed``,
``patch_embed.proj``, ``blocks.N.{norm1, attn.qkv, attn.proj, norm2, mlp.fc1, mlp.fc2}``, ``norm``.
A timm ViT checkpoint of the same width, depth and patch size therefore loads with strict key
checking (``load_timm_weights``). ``exportable=True`` (timm's ``set_layer_config(exportable=True)``)
replaces ``F.scaled_dot_product_attention`` by explicit matmul + softmax, which every ONNX opset
and runtime reproduces.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import nn


def attention(q: torch.Tensor, k: torch.Tensor, v: torch.Tensor, scale: float, fused: bool) -> torch.Tensor:
    """Scaled dot-product attention (scale = d ** -0.5). q [B, h, Nq, d], k/v [B, h, Nk, d] -> [B, h, Nq, d].

    The unfused path is timm's exportable one: q is scaled before the matmul (no fp16 overflow in
    q k^T) and the softmax is a single op.
    """
    if fused:
        return F.scaled_dot_product_attention(q, k, v, scale=scale)
    q = q * scale
    return (q @ k.transpose(-2, -1)).softmax(dim=-1) @ v


class PatchEmbed(nn.Module):
    """Image [B, 3, H, W] -> patch tokens [B, (H/p)(W/p), C] by a strided conv."""

    def __init__(self, img_size: int, patch_size: int, in_chans: int, embed_dim: int) -> None:
        super().__init__()
        self.img_size = img_size
        self.patch_size = patch_size
        self.grid_size = img_size // patch_size
        self.num_patches = self.grid_size**2
        self.proj = nn.Conv2d(in_chans, embed_dim, kernel_size=patch_size, stride=patch_size)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.proj(x).flatten(2).transpose(1, 2)


class Attention(nn.Module):
    """Multi-head self-attention with a fused qkv projection (timm's ``Attention``)."""

    def __init__(self, dim: int, num_heads: int, fused_attn: bool = True) -> None:
        super().__init__()
        self.num_heads = num_heads
        self.head_dim = dim // num_heads
        self.scale = self.head_dim**-0.5
        self.fused_attn = fused_attn
        self.qkv = nn.Linear(dim, dim * 3)
        self.proj = nn.Linear(dim, dim)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """x [B, N, C] -> [B, N, C]."""
        n, c = x.shape[1], x.shape[2]
        qkv = self.qkv(x).reshape(-1, n, 3, self.num_heads, self.head_dim).permute(2, 0, 3, 1, 4)
        x = attention(qkv[0], qkv[1], qkv[2], self.scale, self.fused_attn)
        return self.proj(x.transpose(1, 2).reshape(-1, n, c))


class Mlp(nn.Module):
    """fc1 -> GELU (erf) -> fc2 (timm's ``Mlp``)."""

    def __init__(self, dim: int, hidden: int) -> None:
        super().__init__()
        self.fc1 = nn.Linear(dim, hidden)
        self.act = nn.GELU()
        self.fc2 = nn.Linear(hidden, dim)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.fc2(self.act(self.fc1(x)))


class Block(nn.Module):
    """Pre-norm transformer block: x + attn(norm1(x)), then x + mlp(norm2(x))."""

    def __init__(self, dim: int, num_heads: int, mlp_ratio: float, fused_attn: bool) -> None:
        super().__init__()
        self.norm1 = nn.LayerNorm(dim, eps=1e-6)
        self.attn = Attention(dim, num_heads, fused_attn=fused_attn)
        self.norm2 = nn.LayerNorm(dim, eps=1e-6)
        self.mlp = Mlp(dim, int(dim * mlp_ratio))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = x + self.attn(self.norm1(x))
        return x + self.mlp(self.norm2(x))


class VisionTransformer(nn.Module):
    """Class token + learned position embedding + ``depth`` blocks + final LayerNorm; no classifier."""

    def __init__(
        self,
        img_size: int,
        patch_size: int,
        embed_dim: int,
        depth: int,
        num_heads: int,
        mlp_ratio: float = 4.0,
        in_chans: int = 3,
        exportable: bool = False,
    ) -> None:
        super().__init__()
        self.embed_dim = embed_dim
        self.patch_embed = PatchEmbed(img_size, patch_size, in_chans, embed_dim)
        self.cls_token = nn.Parameter(torch.zeros(1, 1, embed_dim))
        self.pos_embed = nn.Parameter(torch.zeros(1, self.patch_embed.num_patches + 1, embed_dim))
        self.blocks = nn.Sequential(*(Block(embed_dim, num_heads, mlp_ratio, not exportable) for _ in range(depth)))
        self.norm = nn.LayerNorm(embed_dim, eps=1e-6)
        self._init_weights()

    def _init_weights(self) -> None:
        """timm's default init: trunc-normal 0.02 for linears and positions, a tiny class token."""
        nn.init.trunc_normal_(self.pos_embed, std=0.02)
        nn.init.normal_(self.cls_token, std=1e-6)
        for m in self.modules():
            if isinstance(m, nn.Linear):
                nn.init.trunc_normal_(m.weight, std=0.02)
                nn.init.zeros_(m.bias)

    def forward_features(self, x: torch.Tensor) -> torch.Tensor:
        """Image [B, 3, H, W] (normalised) -> tokens [B, 1 + N, C], class token first."""
        x = self.patch_embed(x)
        x = torch.cat([self.cls_token.expand(x.shape[0], -1, -1), x], dim=1) + self.pos_embed
        return self.norm(self.blocks(x))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Image [B, 3, H, W] -> patch features [B, N, C] (the class token dropped)."""
        return self.forward_features(x)[:, 1:]


def resample_pos_embed(pos_embed: torch.Tensor, grid: int) -> torch.Tensor:
    """[1, 1 + g*g, C] -> [1, 1 + grid*grid, C]: bicubic resampling of the patch positions, as timm
    does when a checkpoint's image size differs; the class-token position is kept."""
    cls_pos, patch_pos = pos_embed[:, :1], pos_embed[:, 1:]
    old = math.isqrt(patch_pos.shape[1])
    if old * old != patch_pos.shape[1]:
        raise ValueError(f"pos_embed: {patch_pos.shape[1]} patch positions do not form a square grid")
    patch_pos = patch_pos.reshape(1, old, old, -1).permute(0, 3, 1, 2)
    patch_pos = F.interpolate(patch_pos, size=(grid, grid), mode="bicubic", align_corners=False)
    return torch.cat([cls_pos, patch_pos.permute(0, 2, 3, 1).reshape(1, grid * grid, -1)], dim=1)


def read_state_dict(path: str | os.PathLike) -> dict[str, torch.Tensor]:
    """Tensors from a local ``.safetensors`` file or a torch file (loaded with weights_only=True;
    a ``{'model': ...}`` or ``{'state_dict': ...}`` wrapper is unwrapped)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"pretrained_path: {path}: no such file")
    if path.suffix == ".safetensors":
        try:
            from safetensors.torch import load_file
        except ImportError:
            raise ImportError(f"pretrained_path: {path}: reading .safetensors needs the 'safetensors' package") from None
        return load_file(str(path))
    state = torch.load(path, map_location="cpu", weights_only=True)
    for key in ("model", "state_dict"):
        if isinstance(state, dict) and isinstance(state.get(key), dict):
            state = state[key]
    if not isinstance(state, dict):
        raise ValueError(f"pretrained_path: {path}: holds a {type(state).__name__}, not a state dict")
    return state


# timm keys the backbone has no counterpart for: the classifier of a checkpoint trained with one
# (timm drops it the same way when a model is created with num_classes=0).
_CLASSIFIER_KEYS = ("head.weight", "head.bias")


def load_timm_weights(vit: VisionTransformer, state: dict[str, torch.Tensor], source: str = "state dict") -> None:
    """Load a timm ``VisionTransformer`` state dict into ``vit`` with strict key checking.

    The classifier (``head.*``) is ignored and ``pos_embed`` is resampled to this image size; any
    other missing or unexpected key, or a shape mismatch, raises a ValueError listing them.
    """
    state = {k: v for k, v in state.items() if k not in _CLASSIFIER_KEYS}
    own = vit.state_dict()
    missing = sorted(set(own) - set(state))
    unexpected = sorted(set(state) - set(own))
    if missing or unexpected:
        raise ValueError(
            f"{source}: keys do not match the ViT backbone: missing {missing or 'none'}; unexpected {unexpected or 'none'}"
        )
    pos = state["pos_embed"]
    if pos.shape != own["pos_embed"].shape and pos.ndim == 3 and pos.shape[2] == own["pos_embed"].shape[2]:
        state = {**state, "pos_embed": resample_pos_embed(pos.float(), vit.patch_embed.grid_size)}
    wrong = [f"{k}: {tuple(state[k].shape)} vs {tuple(v.shape)}" for k, v in own.items() if state[k].shape != v.shape]
    if wrong:
        raise ValueError(f"{source}: tensor shapes do not match the ViT backbone (checkpoint vs model): {wrong}")
    vit.load_state_dict(state, strict=True)
