"""Training configuration: one dataclass, named presets, saved resolved with every run."""

from __future__ import annotations

import dataclasses
import hashlib
import json
from dataclasses import dataclass, field
from typing import Any

from trioman.runtime.options import check_options, integer, number, option
from trioman.toolkit.avatar.config import AvatarConfig
from trioman.toolkit.loops.settings import check_loop_settings
from trioman.toolkit.train.augment_config import AugmentConfig


@dataclass(frozen=True)
class LossWeights:
    l1: float = 0.8
    ssim: float = 0.2
    lpips: float = 0.2  # used only when LPIPS backbone weights are available locally
    offset: float = 10.0  # L2 of the canonical position offsets (m^2)
    scale: float = 0.1  # L2 of the log-scale offsets
    lap_offset: float = 1e4  # Laplacian of the position offsets
    lap_scale: float = 1.0  # Laplacian of the log-scale offsets
    delta_offset: float = 100.0  # L2 of the pose-dependent offsets
    delta_rgb: float = 0.1  # L2 of the pose-dependent colour logits (novel poses extrapolate them)
    pose_correction: float = 1.0  # L2 of a frame's learnt pose correction (mean rad^2 per joint + root m^2)


@dataclass(frozen=True)
class TrainConfig:
    preset: str = option("quick", choices=("quick", "full"), help="training preset")
    iterations: int = option(1500, check=integer(1), default_text="the preset's: quick 1000, full 6000",
                             help="optimisation steps")
    lr: float = 1e-3
    lr_decay_at: tuple[float, float] = (0.75, 0.95)  # x0.1 then x0.01 at these fractions of the run
    point_color_lr: float = 1e-2  # learning rate of the per-Gaussian colours (avatar.point_colors), same decay
    image_scale: float = option(1.0, check=number(0.05, 1), help="train on images resized by this factor, in [0.05, 1] "
                                "(the intrinsics scaled to match)")
    supervise_plain: bool = False  # also render and supervise the pose-independent set (ExAvatar does)
    frames: str = "train"  # the frames trained on: "train" (the train split) or "all" (every frame)
    frame_stride: int = 1  # keep every frame_stride-th of those frames (a subset, for coarse-render corpora)
    random_background: bool = True
    extra_frames: str | None = option(None, metavar="DIR", help="also train on this subject folder of pseudo-GT "
                                      "frames (trioman augment --out DIR), sampled with the subject's frames")
    extra_weight: float = option(1.0, check=number(0), help="loss weight of the --extra-frames frames")
    augment: AugmentConfig | None = None  # online augmentation (toolkit/train/augmentation.py); None: off
    refine_poses: bool | None = option(None, default_text="on for a subject written by trioman fit, unless augmenting",
                                       help="learn corrections of the subject's poses with the avatar (poses fitted to "
                                            "a video; toolkit/train/pose_corrections.py): the held-out frames take the "
                                            "corrections of the frames around them")
    pose_lr: float = 3e-4  # learning rate of the pose corrections (rad, m; same decay)
    pose_start: float = 0.3  # share of the iterations before the corrections learn (an early avatar misleads them)
    pose_knot_every: int = 4  # frames between the corrections' knots along a sequence
    checkpoint_every: int = 250
    max_skipped: int = 10  # consecutive steps with a non-finite loss or gradient (skipped) that stop the run
    keep_checkpoints: int = 2
    seed: int = option(0, check=integer(), help="the run's seed")
    weights: LossWeights = field(default_factory=LossWeights)
    avatar: AvatarConfig = field(default_factory=AvatarConfig)

    def __post_init__(self) -> None:
        check_options(self)
        if self.frames not in ("train", "all"):
            raise ValueError(f"frames: expected 'train' or 'all', got {self.frames!r}")
        check_loop_settings(self)
        if self.frame_stride < 1:
            raise ValueError(f"frame_stride: must be >= 1, got {self.frame_stride}")
        if not 0.0 <= self.pose_start < 1.0:
            raise ValueError(f"pose_start: must lie in [0, 1), got {self.pose_start}")
        if self.pose_knot_every < 1:
            raise ValueError(f"pose_knot_every: must be >= 1, got {self.pose_knot_every}")
        for name in ("lr", "point_color_lr", "pose_lr"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name}: must be > 0, got {getattr(self, name)}")
        if self.extra_frames is not None and (not isinstance(self.extra_frames, str) or not self.extra_frames):
            raise ValueError(f"extra_frames: expected a subject folder path or None, got {self.extra_frames!r}")

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "TrainConfig":
        """The inverse of ``to_dict``; a key this version does not know is an error naming it."""
        d = _known(cls, dict(d), "")
        d["weights"] = LossWeights(**_known(LossWeights, dict(d.get("weights", {})), "weights."))
        d["avatar"] = AvatarConfig(**_known(AvatarConfig, dict(d.get("avatar", {})), "avatar."))
        if d.get("augment") is not None:
            d["augment"] = AugmentConfig.from_dict(d["augment"])
        d["lr_decay_at"] = tuple(d.get("lr_decay_at", (0.75, 0.95)))
        return cls(**d)

    def digest(self) -> str:
        return hashlib.sha1(json.dumps(self.to_dict(), sort_keys=True).encode()).hexdigest()[:12]


def _known(cls: type, d: dict[str, Any], prefix: str) -> dict[str, Any]:
    unknown = sorted(set(d) - {f.name for f in dataclasses.fields(cls)})
    if unknown:
        raise ValueError(f"{prefix}{unknown[0]}: not a training setting of this trioman version (a run of another one?)")
    return d


# quick: a CPU-sized strong baseline; no pose-dependent MLPs, whose offsets extrapolate to novel poses
# (docs/findings.md, "Avatar"). full: ExAvatar's setting for real captures (pose-dependent, both sets supervised),
# the pose-dependent MLPs on the body mesh's own vertices, carried to the twice-subdivided Gaussians.
PRESETS: dict[str, TrainConfig] = {
    "quick": TrainConfig(preset="quick", iterations=1000, avatar=AvatarConfig(
        subdivisions=1, point_colors=True, scale_init=1.0, pose_dependent=False, triplane_res=64, hidden=64)),
    "full": TrainConfig(preset="full", iterations=6000, supervise_plain=True, avatar=AvatarConfig(
        subdivisions=2, point_colors=True, scale_init=1.0, triplane_res=128, pose_subdivisions=0)),
}


FITTED_BY = "trioman fit"  # subject.json's generator.tool of a subject whose poses were fitted to its video


def with_subject_defaults(cfg: TrainConfig, tool: str | None) -> TrainConfig:
    """``cfg`` with the settings it leaves to the subject resolved (``tool``: subject.json's generator.tool):
    ``refine_poses`` None is on for a subject fitted to its video by trioman fit when not augmenting (the
    corrections' gain was measured without augmentation: docs/fit.md), else off."""
    if cfg.refine_poses is not None:
        return cfg
    return dataclasses.replace(cfg, refine_poses=tool == FITTED_BY and cfg.augment is None)


def preset(name: str, **overrides: Any) -> TrainConfig:
    if name not in PRESETS:
        raise ValueError(f"preset: unknown preset {name!r}; available: {sorted(PRESETS)}")
    return dataclasses.replace(PRESETS[name], **overrides)
