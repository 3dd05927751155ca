"""Corrections of a subject's stored poses, learnt with the avatar (``TrainConfig.refine_poses``).

Poses fitted to a video (``trioman fit``) carry errors of a few degrees per joint that move slowly along the
video; an avatar trained at them blurs what the frames disagree on, and its test frames are rendered at poses
as wrong. The corrections are a piecewise-linear function of the frame's place in its sequence: knots every
``knot_every`` frames (and at each sequence's last frame), a joint-rotation offset [J, 3] (axis-angle, added to
the stored one) and a root offset [3] (m) per knot. A frame's correction interpolates its two knots, so the
held-out frames between training frames take the correction their neighbours learnt, from no test pixel.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn


class PoseCorrections(nn.Module):
    """Per-frame pose and root offsets of a subject, interpolated between knots along each sequence."""

    def __init__(self, sequence: np.ndarray, joints: int, knot_every: int):
        """sequence: [F] str, every subject frame's sequence (frames in time order within a sequence)."""
        super().__init__()
        if knot_every < 1:
            raise ValueError(f"knot_every: must be >= 1, got {knot_every}")
        lo, hi, w, knots = np.zeros(len(sequence), np.int64), np.zeros(len(sequence), np.int64), np.zeros(len(sequence)), 0
        for name in dict.fromkeys(sequence.tolist()):
            frames = np.flatnonzero(sequence == name)
            at = np.unique(np.append(np.arange(0, len(frames), knot_every), len(frames) - 1))  # knot positions
            k = np.clip(np.searchsorted(at, np.arange(len(frames)), side="right") - 1, 0, max(len(at) - 2, 0))
            k1 = np.minimum(k + 1, len(at) - 1)
            span = np.maximum(at[k1] - at[k], 1)
            lo[frames], hi[frames] = knots + k, knots + k1
            w[frames] = np.clip((np.arange(len(frames)) - at[k]) / span, 0.0, 1.0)
            knots += len(at)
        self.register_buffer("lo", torch.from_numpy(lo), persistent=False)
        self.register_buffer("hi", torch.from_numpy(hi), persistent=False)
        self.register_buffer("w", torch.from_numpy(w.astype(np.float32)), persistent=False)
        self.pose = nn.Parameter(torch.zeros(knots, joints, 3))  # [K, J, 3] axis-angle offsets (rad)
        self.trans = nn.Parameter(torch.zeros(knots, 3))  # [K, 3] root offsets (m)

    def forward(self, frame: int | torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Subject frame index (or [M] indices) -> (pose offset [(M,) J, 3], root offset [(M,) 3])."""
        lo, hi, w = self.lo[frame], self.hi[frame], self.w[frame]

        def mix(knots: torch.Tensor) -> torch.Tensor:
            weight = w.reshape(w.shape + (1,) * (knots.ndim - 1))
            return (1 - weight) * knots[lo] + weight * knots[hi]

        return mix(self.pose), mix(self.trans)

    def apply(self, frame: int, pose: torch.Tensor, trans: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The stored pose [J, 3] and root [3] of subject frame ``frame`` corrected."""
        d_pose, d_trans = self(frame)
        return pose + d_pose, trans + d_trans

    @torch.no_grad()
    def all(self, poses: np.ndarray, trans: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Every frame corrected: poses [F, J, 3], trans [F, 3] -> the same, float32."""
        d_pose, d_trans = self(torch.arange(len(self.w)))
        return ((torch.from_numpy(np.array(poses, np.float32)) + d_pose).numpy(),
                (torch.from_numpy(np.array(trans, np.float32)) + d_trans).numpy())

    def penalty(self, frame: int) -> torch.Tensor:
        """Mean squared joint offset (rad^2) plus squared root offset (m^2) of the frame's correction."""
        d_pose, d_trans = self(frame)
        return d_pose.square().sum(-1).mean() + d_trans.square().sum()
