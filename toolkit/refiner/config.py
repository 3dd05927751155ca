"""Refiner configuration: one frozen dataclass, validated on construction, saved with checkpoints."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

from trioman.toolkit.corpus_training_options import CONDITIONS  # noqa: F401  (the Refiner's conditions, declared there)

VIEW_COUNT = {"none": 1, "tex": 2, "tex+geo": 3, "warp": 2, "warp+geo": 3}
ALIGNED_CONDITIONS = ("warp", "warp+geo")
_TUPLE_FIELDS = ("vae_widths", "unet_widths")


@dataclass(frozen=True)
class RefinerConfig:
    """Sizes of the Refiner (see :mod:`trioman.toolkit.refiner.model` for the architecture).

    Images [B, 3, H, W] go to latents [B, latent_channels, H / latent_downsample, W / latent_downsample];
    the U-Net halves the latent ``len(unet_widths) - 1`` times, so H and W must be multiples of
    ``total_downsample`` (16 with the defaults). ``image_size`` is the size used for training and
    export examples; the torch model runs on any multiple of ``total_downsample``.
    """

    image_size: int = 128
    latent_channels: int = 8  # c of the latents z_c, z_t, z_g
    latent_downsample: int = 4  # a power of two: the encoders halve H, W log2 of it times
    vae_widths: tuple[int, ...] = (32, 64, 96)  # encoder/decoder widths, full res first; log2(latent_downsample) + 1 entries
    unet_widths: tuple[int, ...] = (64, 128, 128)  # one per U-Net level (the level count is its length)
    attention_from_level: int = 1  # cross-view self-attention at this level and below (lower res); the middle always has it
    attention_heads: int = 4  # divides every U-Net width that has attention
    norm_groups: int = 8  # GroupNorm groups; divides every width
    conditions: str = "tex+geo"  # one of CONDITIONS
    residual: bool = True  # each view's output = sigmoid(logit(its input) + decoded); False: sigmoid(decoded)
    backbone: str = "scratch"  # a name registered with register_backbone
    pretrained_path: str | None = None  # local weights folder for a pretrained backbone (never downloaded)

    def __post_init__(self) -> None:
        for name in _TUPLE_FIELDS:
            object.__setattr__(self, name, tuple(getattr(self, name)))
        for name in ("image_size", "latent_channels", "latent_downsample", "attention_heads", "norm_groups"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ValueError(f"{name}: must be a positive integer, got {value!r}")
        if self.latent_downsample & (self.latent_downsample - 1):
            raise ValueError(f"latent_downsample: must be a power of two, got {self.latent_downsample}")
        for name in _TUPLE_FIELDS:
            widths = getattr(self, name)
            if not widths or any(not isinstance(w, int) or isinstance(w, bool) or w < 1 for w in widths):
                raise ValueError(f"{name}: expected a non-empty tuple of positive integers, got {widths!r}")
            for i, w in enumerate(widths):
                if w % self.norm_groups:
                    raise ValueError(f"{name}[{i}]: {w} is not divisible by norm_groups {self.norm_groups}")
        stages = self.latent_downsample.bit_length() - 1
        if len(self.vae_widths) != stages + 1:
            raise ValueError(
                f"vae_widths: expected {stages + 1} entries for latent_downsample {self.latent_downsample}, got {len(self.vae_widths)}"
            )
        levels = len(self.unet_widths)
        if not isinstance(self.attention_from_level, int) or not 0 <= self.attention_from_level <= levels:
            raise ValueError(f"attention_from_level: must be an integer in [0, {levels}], got {self.attention_from_level!r}")
        for i in range(min(self.attention_from_level, levels - 1), levels):  # the middle runs at the last width
            if self.unet_widths[i] % self.attention_heads:
                raise ValueError(f"unet_widths[{i}]: {self.unet_widths[i]} is not divisible by attention_heads {self.attention_heads}")
        if self.conditions not in CONDITIONS:
            raise ValueError(f"conditions: expected one of {CONDITIONS}, got {self.conditions!r}")
        if not isinstance(self.residual, bool):
            raise ValueError(f"residual: must be a bool, got {self.residual!r}")
        if not isinstance(self.backbone, str) or not self.backbone:
            raise ValueError(f"backbone: must be a non-empty name, got {self.backbone!r}")
        if self.pretrained_path is not None and not isinstance(self.pretrained_path, str):
            raise ValueError(f"pretrained_path: must be a string path or None, got {self.pretrained_path!r}")
        if self.image_size % self.total_downsample:
            raise ValueError(f"image_size: {self.image_size} is not a multiple of the total downsampling {self.total_downsample}")

    @property
    def views(self) -> int:
        """V, the number of stacked latents: 1, 2 or 3 by ``conditions``."""
        return VIEW_COUNT[self.conditions]

    @property
    def total_downsample(self) -> int:
        """Image size / smallest U-Net resolution: H and W must be multiples of it."""
        return self.latent_downsample * 2 ** (len(self.unet_widths) - 1)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "RefinerConfig":
        unknown = sorted(set(d) - {f.name for f in dataclasses.fields(cls)})
        if unknown:
            raise ValueError(f"config: unknown Refiner config fields {unknown}")
        return cls(**d)
