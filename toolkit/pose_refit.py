"""Poses refitted to each frame's own pixels with the avatar frozen (``trioman eval --poses optimised``).

Poses fitted to a video are wrong by a few degrees per joint, and a held-out frame's error is one no training pixel
saw: its render then measures the pose as much as the avatar. Avatar papers evaluated on real captures therefore
often refit each test frame's pose to its image with the avatar frozen (test-time pose optimisation). Here: the
joint rotations and the root of every frame, from the given poses, by Adam on the training loss (L1 + SSIM) over
white, a penalty on the change, at ``scale`` of the image size. The frame's pixels are used, so the numbers it
gives are an avatar's quality at its best-fitting pose, not a prediction; reports say which poses they used.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import torch

from trioman.runtime.formats import Subject
from trioman.toolkit.avatar.model import GaussianAvatar
from trioman.toolkit.train.data import load_frames


@dataclass(frozen=True)
class RefitSettings:
    steps: int = 20  # Adam steps per frame
    lr: float = 5e-3  # rad (and m) per step
    penalty: float = 1.0  # weight of the change's mean squared joint rotation (rad^2) plus squared root shift (m^2)
    scale: float = 0.5  # of the subject's image size

    def __post_init__(self) -> None:
        if isinstance(self.steps, bool) or not isinstance(self.steps, int) or self.steps < 1:
            raise ValueError(f"steps: must be an integer >= 1, got {self.steps!r}")
        if not self.lr > 0:
            raise ValueError(f"lr: must be > 0, got {self.lr}")
        if not self.penalty >= 0:
            raise ValueError(f"penalty: must be >= 0, got {self.penalty}")
        if not 0.05 <= self.scale <= 1.0:
            raise ValueError(f"scale: must lie in [0.05, 1], got {self.scale}")


def refit_poses(model: GaussianAvatar, subject: Subject, split: str, poses: np.ndarray, trans: np.ndarray,
                loss_fn: Callable, render_fn: Callable, settings: RefitSettings = RefitSettings(),
                progress: Callable[[int], None] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Every frame of ``split`` refitted from ``poses`` [F, J, 3] and ``trans`` [F, 3] (all the subject's frames);
    ``loss_fn(img, gt)``, ``render_fn(gaussians, viewmat, K, width, height, bg)``. A frame whose loss turns
    non-finite keeps its pose. -> (poses, trans) with the split's frames replaced, float32."""
    frames = load_frames(subject, split, settings.scale)
    out_poses, out_trans = np.array(poses, np.float32), np.array(trans, np.float32)
    was = [p.requires_grad for p in model.parameters()]
    for p in model.parameters():
        p.requires_grad_(False)
    bg = torch.ones(3)
    try:
        with torch.no_grad():
            pose_free = model.pose_free()
        for k, i in enumerate(frames.indices):
            image, mask = frames.image(k), frames.mask(k)
            gt = image + (1 - mask)[..., None] * bg
            pose0, trans0 = torch.from_numpy(out_poses[i]), torch.from_numpy(out_trans[i])
            d_pose = torch.zeros_like(pose0, requires_grad=True)
            d_root = torch.zeros_like(trans0, requires_grad=True)
            opt = torch.optim.Adam([d_pose, d_root], lr=settings.lr)
            for _ in range(settings.steps):
                g = model(pose0 + d_pose, trans0 + d_root, pose_free).refined
                img = render_fn(g, frames.viewmat[k], frames.K[k], frames.width, frames.height, bg)
                loss = loss_fn(img, gt) + settings.penalty * (d_pose.square().sum(-1).mean() + d_root.square().sum())
                if not torch.isfinite(loss):
                    d_pose, d_root = torch.zeros_like(pose0), torch.zeros_like(trans0)
                    break
                opt.zero_grad(set_to_none=True)
                loss.backward()
                opt.step()
            out_poses[i] = (pose0 + d_pose.detach()).numpy()
            out_trans[i] = (trans0 + d_root.detach()).numpy()
            if progress is not None:
                progress(k + 1)
    finally:
        for p, g in zip(model.parameters(), was):
            p.requires_grad_(g)
    return out_poses, out_trans
