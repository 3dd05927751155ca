"""The Examiner (paper 3.2.6): a dual-branch attention network scoring how well a candidate frame matches
a real reference frame, in [0, 1] (``Examiner``).

Its architecture and the choices the paper leaves open: docs/design.md, "Examiner (3.2.6)".
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any, NamedTuple

import torch
import torch.nn.functional as F
from torch import nn

from trioman.toolkit.examiner.vit import VisionTransformer, attention, load_timm_weights, read_state_dict
from trioman.toolkit.metrics import gaussian_1d, gaussian_window_size


DUAL_ATTENTION = ("channel", "token")


@dataclass(frozen=True)
class ExaminerConfig:
    img_size: int = 128
    patch_size: int = 16
    embed_dim: int = 192  # C, the ViT width
    depth: int = 12
    num_heads: int = 3
    mlp_ratio: float = 4.0
    dual_dims: tuple[int, ...] = (96, 48)  # C^1 .. C^n; n = len(dual_dims) dual blocks
    dual_heads: int = 2  # heads of the dual attention; divides C and every C^i but the last
    conv_kernel: int = 3  # squeeze conv kernel (odd; 1 = channel mixing only)
    head_hidden: int = 64  # hidden width of the score and weight MLPs
    dual_attention: str = "channel"  # "channel": C x C attention map between channels; "token": N x N
    detail_gain: float = 0.0  # > 0: add this times the image's detail layer to the ViT's input
    detail_sigma: float = 1.0  # Gaussian blur (px) that defines the detail layer

    def __post_init__(self) -> None:
        object.__setattr__(self, "dual_dims", tuple(self.dual_dims))
        for name in ("img_size", "patch_size", "embed_dim", "depth", "num_heads", "dual_heads", "conv_kernel", "head_hidden"):
            value = getattr(self, name)
            if not isinstance(value, int) or value < 1:
                raise ValueError(f"{name}: must be a positive integer, got {value!r}")
        if self.img_size % self.patch_size:
            raise ValueError(f"img_size: {self.img_size} is not a multiple of patch_size {self.patch_size}")
        if self.embed_dim % self.num_heads:
            raise ValueError(f"embed_dim: {self.embed_dim} is not divisible by num_heads {self.num_heads}")
        if not self.mlp_ratio > 0:
            raise ValueError(f"mlp_ratio: must be > 0, got {self.mlp_ratio}")
        if not self.dual_dims or any(not isinstance(d, int) or d < 1 for d in self.dual_dims):
            raise ValueError(f"dual_dims: expected a non-empty tuple of positive integers, got {self.dual_dims!r}")
        for name, dim in [("embed_dim", self.embed_dim)] + [(f"dual_dims[{i}]", d) for i, d in enumerate(self.dual_dims[:-1])]:
            if dim % self.dual_heads:
                raise ValueError(f"{name}: {dim} is not divisible by dual_heads {self.dual_heads}")
        if self.dual_attention not in DUAL_ATTENTION:
            raise ValueError(f"dual_attention: expected one of {DUAL_ATTENTION}, got {self.dual_attention!r}")
        for name in ("detail_gain", "detail_sigma"):
            value = getattr(self, name)
            if not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0 or (name == "detail_sigma" and value == 0):
                raise ValueError(f"{name}: must be a finite number {'> 0' if name == 'detail_sigma' else '>= 0'}, got {value!r}")
        if self.conv_kernel % 2 == 0:
            raise ValueError(f"conv_kernel: must be odd, got {self.conv_kernel}")

    @property
    def grid_size(self) -> int:
        return self.img_size // self.patch_size

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "ExaminerConfig":
        unknown = sorted(set(d) - {f.name for f in dataclasses.fields(cls)})
        if unknown:
            raise ValueError(f"config: unknown Examiner config fields {unknown}")
        # configs saved before dual_attention existed describe token-attention models
        return cls(**{"dual_attention": "token", **d})


# Named configurations. examiner_tiny / examiner_small have the backbone layout of timm's
# vit_tiny_patch16_224 / vit_small_patch16_224, so those checkpoints load (pos_embed resampled), and
# the plain input pretrained weights expect. examiner_nano is the from-scratch CPU model, with the
# detail input at gain 16 (the choice and its measurements: docs/findings.md, "Examiner").
EXAMINER_CONFIGS: dict[str, ExaminerConfig] = {
    "examiner_nano": ExaminerConfig(patch_size=8, embed_dim=96, depth=4, num_heads=3, dual_dims=(64, 32), detail_gain=16.0),
    "examiner_tiny": ExaminerConfig(),
    "examiner_small": ExaminerConfig(embed_dim=384, depth=12, num_heads=6, dual_dims=(192, 96, 48)),
}


def examiner_config(name: str, **overrides: Any) -> ExaminerConfig:
    """The named config with ``overrides`` applied (validated)."""
    if name not in EXAMINER_CONFIGS:
        raise ValueError(f"name: unknown Examiner config {name!r}; available: {sorted(EXAMINER_CONFIGS)}")
    return dataclasses.replace(EXAMINER_CONFIGS[name], **overrides)


class PatchLogits(NamedTuple):
    """Per-patch logits of one branch: scores s and weights w, each [B, N]."""

    scores: torch.Tensor
    weights: torch.Tensor

    def score(self) -> torch.Tensor:
        """[B]: sum over patches of softmax(w) * sigmoid(s), in [0, 1]."""
        return (self.weights.softmax(dim=-1) * self.scores.sigmoid()).sum(dim=-1)


class DualAttention(nn.Module):
    """One attention layer for both branches: Q from the reference only, K/V from each branch."""

    def __init__(self, dim: int, num_heads: int, fused_attn: bool, kind: str = "channel") -> None:
        super().__init__()
        self.kind = kind
        self.num_heads = num_heads
        self.head_dim = dim // num_heads
        self.scale = self.head_dim**-0.5
        self.fused_attn = fused_attn
        self.q = nn.Linear(dim, dim)
        self.kv = nn.Linear(dim, 2 * dim)
        self.proj = nn.Linear(dim, dim)
        if kind == "channel":
            self.temperature = nn.Parameter(torch.ones(num_heads, 1, 1))

    def _split(self, x: torch.Tensor, parts: int) -> torch.Tensor:
        """[B, N, parts*C] -> [parts, B, heads, N, d]."""
        return x.reshape(-1, x.shape[1], parts, self.num_heads, self.head_dim).permute(2, 0, 3, 1, 4)

    def _merge(self, x: torch.Tensor) -> torch.Tensor:
        """[B, heads, N, d] -> [B, N, C] through the output projection."""
        return self.proj(x.transpose(1, 2).reshape(-1, x.shape[2], self.num_heads * self.head_dim))

    def forward(self, x_c: torch.Tensor, x_k: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Normalised candidate / reference tokens [B, N, C] -> (upper, lower) outputs [B, N, C]."""
        q = self._split(self.q(x_k), 1)[0]  # Q(f_k), recorded for the upper branch
        kv_k, kv_c = self._split(self.kv(x_k), 2), self._split(self.kv(x_c), 2)
        if self.kind == "channel":
            return self._merge(self._channel(q, kv_c[0], kv_c[1])), self._merge(self._channel(q, kv_k[0], kv_k[1]))
        upper = attention(q, kv_c[0], kv_c[1], self.scale, self.fused_attn)
        lower = attention(q, kv_k[0], kv_k[1], self.scale, self.fused_attn)
        return self._merge(upper), self._merge(lower)

    def _channel(self, q: torch.Tensor, k: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
        """Cross-covariance attention (XCiT): q, k, v [B, h, N, d] -> [B, h, N, d]. The [d, d] map
        softmax_j(t * <q_i, k_j>) compares channel i of the query image with channel j of the key
        image over all patches (q, k L2-normalised along the patches); each patch's output mixes the
        channels of v at that same patch, so the key image's local detail is kept."""
        q = F.normalize(q, dim=-2, eps=1e-6)
        k = F.normalize(k, dim=-2, eps=1e-6)
        attn = (q.transpose(-2, -1) @ k * self.temperature).softmax(dim=-1)  # [B, h, d, d]
        return v @ attn.transpose(-2, -1)


class DualBlock(nn.Module):
    """Dual attention, the residual, then a shared conv squeezing C -> C_out on the patch grid."""

    def __init__(self, dim: int, out_dim: int, num_heads: int, grid: int, kernel: int, fused_attn: bool,
                 kind: str = "channel") -> None:
        super().__init__()
        self.grid = grid
        self.norm = nn.LayerNorm(dim, eps=1e-6)
        self.attn = DualAttention(dim, num_heads, fused_attn, kind)
        self.squeeze = nn.Conv2d(dim, out_dim, kernel_size=kernel, padding=kernel // 2)
        self.act = nn.GELU()

    def _conv(self, x: torch.Tensor) -> torch.Tensor:
        """[B, N, C] -> [B, C, H, W] -> conv -> [B, N, C_out]."""
        x = x.transpose(1, 2).reshape(-1, x.shape[2], self.grid, self.grid)
        return self.act(self.squeeze(x)).flatten(2).transpose(1, 2)

    def forward(self, f_c: torch.Tensor, f_k: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(f_c, f_k) [B, N, C] -> (f_c', f_k') [B, N, C_out]."""
        upper, lower = self.attn(self.norm(f_c), self.norm(f_k))
        # the residual is the stream whose patches the output lives on: the values' (channel) or
        # the queries' (token)
        upper_in = f_c if self.attn.kind == "channel" else f_k
        return self._conv(upper_in + upper), self._conv(f_k + lower)


class Examiner(nn.Module):
    """score(candidate, reference) in [0, 1]; both images [B, 3, S, S] RGB in [0, 1]."""

    def __init__(self, config: ExaminerConfig, exportable: bool = False) -> None:
        super().__init__()
        self.config = config
        c = config
        self.backbone = VisionTransformer(c.img_size, c.patch_size, c.embed_dim, c.depth, c.num_heads, c.mlp_ratio, exportable=exportable)
        dims = (c.embed_dim, *c.dual_dims)
        self.dual_blocks = nn.ModuleList(
            DualBlock(dims[i], dims[i + 1], c.dual_heads, c.grid_size, c.conv_kernel, not exportable, c.dual_attention) for i in range(len(c.dual_dims))
        )
        if c.detail_gain > 0:  # fixed [3, 1, w, w] Gaussian of the detail layer, derived from the config
            g = gaussian_1d(gaussian_window_size(c.detail_sigma), c.detail_sigma, torch.float32, torch.device("cpu"))
            self.register_buffer("detail_kernel", (g[:, None] * g[None, :]).expand(3, 1, -1, -1).clone(), persistent=False)
        self.head_norm = nn.LayerNorm(dims[-1], eps=1e-6)
        self.score_mlp = nn.Sequential(nn.Linear(dims[-1], c.head_hidden), nn.GELU(), nn.Linear(c.head_hidden, 1))
        self.weight_mlp = nn.Sequential(nn.Linear(dims[-1], c.head_hidden), nn.GELU(), nn.Linear(c.head_hidden, 1))

    def check_images(self, name: str, x: torch.Tensor) -> None:
        """ValueError naming ``name`` unless x is a finite float tensor [B, 3, S, S] with S = img_size."""
        s = self.config.img_size
        if not isinstance(x, torch.Tensor) or not x.is_floating_point():
            raise ValueError(f"{name}: expected a float tensor, got {getattr(x, 'dtype', type(x).__name__)}")
        if x.ndim != 4 or x.shape[1] != 3 or x.shape[2] != s or x.shape[3] != s or x.shape[0] == 0:
            raise ValueError(f"{name}: expected shape [B, 3, {s}, {s}] with B >= 1, got {list(x.shape)}")
        if not torch.isfinite(x).all():
            raise ValueError(f"{name}: contains {int((~torch.isfinite(x)).sum())} NaN/Inf values")

    def features(self, images: torch.Tensor) -> torch.Tensor:
        """Images [B, 3, S, S] in [0, 1] -> patch features [B, N, C] (normalised with mean = std = 0.5,
        plus ``detail_gain`` times the detail layer when it is > 0)."""
        x = (images - 0.5) / 0.5
        if self.config.detail_gain > 0:
            r = self.detail_kernel.shape[-1] // 2
            blurred = F.conv2d(F.pad(images, (r, r, r, r), mode="replicate"), self.detail_kernel, groups=3)
            x = x + self.config.detail_gain * (images - blurred)
        return self.backbone(x)

    def branch_logits(self, candidate: torch.Tensor, reference: torch.Tensor) -> tuple[PatchLogits, PatchLogits]:
        """(upper, lower) branch patch logits, each [B, N]; the upper one is the pair's score."""
        if not torch.jit.is_tracing():
            self.check_images("candidate", candidate)
            self.check_images("reference", reference)
            if candidate.shape[0] != reference.shape[0]:
                raise ValueError(f"reference: batch {reference.shape[0]} differs from candidate batch {candidate.shape[0]}")
        feats = self.features(torch.cat([candidate, reference]))  # one backbone pass, shared weights
        b = candidate.shape[0]
        f_c, f_k = feats[:b], feats[b:]
        for block in self.dual_blocks:
            f_c, f_k = block(f_c, f_k)
        return self._heads(f_c), self._heads(f_k)

    def _heads(self, f: torch.Tensor) -> PatchLogits:
        f = self.head_norm(f)
        return PatchLogits(self.score_mlp(f).squeeze(-1), self.weight_mlp(f).squeeze(-1))

    def forward(self, candidate: torch.Tensor, reference: torch.Tensor) -> torch.Tensor:
        """candidate, reference [B, 3, S, S] in [0, 1] -> similarity score [B] in [0, 1]."""
        return self.branch_logits(candidate, reference)[0].score()


def create_examiner(
    name: str | ExaminerConfig = "examiner_tiny",
    *,
    exportable: bool = False,
    pretrained_path: str | None = None,
    **overrides: Any,
) -> Examiner:
    """Build an Examiner from a named config (with ``overrides``) or a config object.

    ``exportable`` uses explicit matmul/softmax attention (ONNX); ``pretrained_path`` is a LOCAL timm
    ViT checkpoint loaded strictly into the backbone (nothing is ever downloaded).
    """
    if isinstance(name, ExaminerConfig):
        config = dataclasses.replace(name, **overrides)
    else:
        config = examiner_config(name, **overrides)
    model = Examiner(config, exportable=exportable)
    if pretrained_path is not None:
        load_timm_weights(model.backbone, read_state_dict(pretrained_path), source=str(pretrained_path))
    return model


def export_inputs(config: ExaminerConfig | Examiner, batch: int = 2, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    """Example (candidate, reference) [batch, 3, S, S] in [0, 1] for tracing (trace with batch >= 2)."""
    if isinstance(config, Examiner):
        config = config.config
    if batch < 1:
        raise ValueError(f"batch: must be >= 1, got {batch}")
    g = torch.Generator().manual_seed(seed)
    shape = (batch, 3, config.img_size, config.img_size)
    return torch.rand(shape, generator=g), torch.rand(shape, generator=g)
