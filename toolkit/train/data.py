"""A subject's frames as tensors, optionally resized for training."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import torch

from trioman.runtime.formats import Subject


@dataclass(frozen=True, eq=False)
class FrameSet:
    indices: np.ndarray  # [F] frame indices in the subject
    images: torch.Tensor  # [F, H, W, 3] premultiplied colour on black
    masks: torch.Tensor  # [F, H, W]
    poses: torch.Tensor  # [F, J, 3]
    trans: torch.Tensor  # [F, 3]
    K: torch.Tensor  # [F, 3, 3] for the (resized) images
    viewmat: torch.Tensor  # [F, 4, 4]
    weights: np.ndarray | None = None  # [F] photometric loss weight per frame; None = 1 for every frame

    @property
    def height(self) -> int:
        return self.images.shape[1]

    @property
    def width(self) -> int:
        return self.images.shape[2]

    def __len__(self) -> int:
        return len(self.indices)

    def sample(self, i: int) -> dict:
        """Frame i as the training step takes it: images/masks/poses/trans/K/viewmat and its loss weight."""
        fields = {k: getattr(self, k)[i] for k in ("images", "masks", "poses", "trans", "K", "viewmat")}
        return {**fields, "weight": 1.0 if self.weights is None else float(self.weights[i])}


def load_frames(subject: Subject, split: str | None, scale: float = 1.0, stride: int = 1) -> FrameSet:
    """Load every ``stride``-th frame of ``split`` (train, test or None for all) into memory, resized by ``scale``."""
    idx = subject.indices(split)[::stride]
    if len(idx) == 0:
        raise ValueError(f"split: subject {subject.root} has no {split!r} frames")
    W, H = max(1, round(subject.width * scale)), max(1, round(subject.height * scale))
    images, masks = [], []
    for i in idx:
        img, mask = subject.image(i), subject.mask(i)
        if (W, H) != (subject.width, subject.height):
            img = cv2.resize(img, (W, H), interpolation=cv2.INTER_AREA)
            mask = cv2.resize(mask, (W, H), interpolation=cv2.INTER_AREA)
        images.append(img)
        masks.append(mask)
    K = subject.K[idx].astype(np.float64).copy()
    K[:, 0] *= W / subject.width  # continuous pixel coordinates scale with the image
    K[:, 1] *= H / subject.height
    return FrameSet(
        indices=idx,
        images=torch.from_numpy(np.stack(images)),
        masks=torch.from_numpy(np.stack(masks)),
        poses=torch.from_numpy(np.array(subject.poses[idx], dtype=np.float32)),
        trans=torch.from_numpy(np.array(subject.trans[idx], dtype=np.float32)),
        K=torch.from_numpy(K.astype(np.float32)),
        viewmat=torch.from_numpy(np.array(subject.viewmat[idx], dtype=np.float32)),
    )


def join_frames(frames: FrameSet, extra: FrameSet, extra_weight: float = 1.0) -> FrameSet:
    """``frames`` then ``extra`` (e.g. pseudo-GT frames of ``trioman augment``), the extra ones weighted by
    ``extra_weight``. ``indices`` keep each frame's index in its own subject. Same image size required."""
    if (extra.height, extra.width) != (frames.height, frames.width):
        raise ValueError(f"extra_frames: images are {extra.width}x{extra.height} (W x H) after scaling, "
                         f"but the subject's are {frames.width}x{frames.height}")
    ones = np.ones(len(frames)) if frames.weights is None else frames.weights
    weights = np.concatenate([ones, np.full(len(extra), float(extra_weight))])
    cat = {name: torch.cat([getattr(frames, name), getattr(extra, name)])
           for name in ("images", "masks", "poses", "trans", "K", "viewmat")}
    return FrameSet(indices=np.concatenate([frames.indices, extra.indices]), weights=weights, **cat)
