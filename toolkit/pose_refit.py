"""Poses refitted to each frame's own pixels with the avatar frozen (``trioman eval --poses optimised``).

Poses fitted to a video are wrong by a few degrees per joint, and a held-out frame's error is one no training pixel
saw: its render then measures the pose as much as the avatar. Avatar papers evaluated on real captures therefore
often refit each test frame's pose to its image with the avatar frozen (test-time pose optimisation). Here: the
joint rotations and the root of every frame, from the given poses, on the training loss (L1 + SSIM) over white plus
a penalty on the change, by L-BFGS with a strong-Wolfe line search: each step's length comes from the loss's own
curvature, so a frame already at its best pose stays there (Adam's first steps move every joint by its learning rate
whatever the gradient, and walk an exact pose away). Refit at the size the metric is measured at: a splat avatar
rendered smaller than it was trained is not its reduced image, and the pose that best matches it is a shifted one.
The frame's pixels are used, so the numbers it gives are an avatar's quality at its best-fitting pose, not a
prediction; reports say which poses they used.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np
import torch

from trioman.runtime.formats import Subject
from trioman.toolkit.avatar.model import GaussianAvatar
from trioman.toolkit.evaluate_config import REFIT_STEPS
from trioman.toolkit.train.data import load_frames


@dataclass(frozen=True)
class RefitSettings:
    steps: int = REFIT_STEPS  # most L-BFGS iterations per frame (each about 1.2 renders with its gradient); a frame ends
    # sooner when L-BFGS converges (its step or its change in loss below 1e-9). A fixed small count is not enough:
    # frames far from their best pose are still rising when frames near it have stopped, which favours the latter
    penalty: float = 1.0  # weight of the change's mean squared joint rotation (rad^2) plus squared root shift (m^2)
    scale: float = 1.0  # of the subject's image size (below 1: faster, biased, see the module's docstring)

    def __post_init__(self) -> None:
        if isinstance(self.steps, bool) or not isinstance(self.steps, int) or self.steps < 1:
            raise ValueError(f"steps: must be an integer >= 1, got {self.steps!r}")
        if not self.penalty >= 0:
            raise ValueError(f"penalty: must be >= 0, got {self.penalty}")
        if not 0.05 <= self.scale <= 1.0:
            raise ValueError(f"scale: must lie in [0.05, 1], got {self.scale}")


def refit_poses(model: GaussianAvatar, subject: Subject, split: str, poses: np.ndarray, trans: np.ndarray,
                loss_fn: Callable, render_fn: Callable, settings: RefitSettings = RefitSettings(),
                progress: Callable[[int], None] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Every frame of ``split`` refitted from ``poses`` [F, J, 3] and ``trans`` [F, 3] (all the subject's frames);
    ``loss_fn(img, gt)``, ``render_fn(gaussians, viewmat, K, width, height, bg)``. A frame keeps its pose when its
    loss is non-finite or the refit did not lower it. -> (poses, trans) with the split's frames replaced, float32."""
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
            pose0, trans0 = torch.from_numpy(out_poses[i]), torch.from_numpy(out_trans[i])

            def loss_at(d: torch.Tensor, k=k, pose0=pose0, trans0=trans0, gt=image + (1 - mask)[..., None] * bg):
                d_pose, d_root = d[:-3].view_as(pose0), d[-3:]
                g = model(pose0 + d_pose, trans0 + d_root, pose_free).refined
                img = render_fn(g, frames.viewmat[k], frames.K[k], frames.width, frames.height, bg)
                return loss_fn(img, gt) + settings.penalty * (d_pose.square().sum(-1).mean() + d_root.square().sum())

            change = _minimise(loss_at, pose0.numel() + 3, settings.steps)
            out_poses[i] = (pose0 + change[:-3].view_as(pose0)).numpy()
            out_trans[i] = (trans0 + change[-3:]).numpy()
            if progress is not None:
                progress(k + 1)
    finally:
        for p, g in zip(model.parameters(), was):
            p.requires_grad_(g)
    return out_poses, out_trans


def _minimise(loss_at: Callable[[torch.Tensor], torch.Tensor], n: int, steps: int) -> torch.Tensor:
    """The change [n] (from zero) that L-BFGS finds in at most ``steps`` iterations; zero when the loss at zero
    is not finite or the search ends no lower than it started."""
    zero = torch.zeros(n)
    with torch.no_grad():
        start = float(loss_at(zero))
    if not math.isfinite(start):
        return zero
    d = zero.clone().requires_grad_(True)
    opt = torch.optim.LBFGS([d], lr=1.0, max_iter=steps, line_search_fn="strong_wolfe")

    def closure() -> torch.Tensor:
        opt.zero_grad(set_to_none=True)
        loss = loss_at(d)
        loss.backward()
        return loss

    opt.step(closure)
    with torch.no_grad():
        end = float(loss_at(d))
    return d.detach() if math.isfinite(end) and end < start and bool(torch.isfinite(d).all()) else zero
