"""A subject's frames for training, optionally resized: pixels kept as uint8, or read lazily when large.

Real captures are large (X-Humans: ~1,400 training frames per subject at up to 800 x 1200): as float32
1,500 frames of 1024 x 1024 would take 25 GB. Frames are therefore held as 8-bit (what the PNGs store:
4 bytes per pixel with the mask) when that fits in ``IN_MEMORY_BYTES``, and otherwise read from disk
(and resized) each time a step draws them. Either way a step sees the same float32 values.
"""

from __future__ import annotations

import abc

from dataclasses import dataclass

import cv2
import numpy as np
import torch

from trioman.runtime.formats import Subject
from trioman.runtime.formats.subject import WEIGHTS_DIR

IN_MEMORY_BYTES = 1 << 30  # frames above this (8-bit image + mask) are read from disk per step


class _Pixels(abc.ABC):
    """Frame i's premultiplied image [H, W, 3] and mask [H, W] as float32 tensors in [0, 1], and its per-pixel
    loss weights [H, W] (None: 1 everywhere)."""

    @abc.abstractmethod
    def __len__(self) -> int:
        """The number of frames."""

    @abc.abstractmethod
    def get(self, i: int) -> tuple[torch.Tensor, torch.Tensor]:
        """Frame i's (image, mask)."""

    def weights(self, i: int) -> torch.Tensor | None:
        return None


class _MemoryPixels(_Pixels):
    def __init__(self, images: np.ndarray, masks: np.ndarray, weights: np.ndarray | None = None):
        self.images, self.masks = torch.from_numpy(images), torch.from_numpy(masks)  # uint8 [F, H, W, 3], [F, H, W]
        self.pixel_weights = None if weights is None else torch.from_numpy(weights)  # uint8 [F, H, W]

    def __len__(self) -> int:
        return len(self.images)

    def get(self, i: int) -> tuple[torch.Tensor, torch.Tensor]:
        return self.images[i].float() / 255.0, self.masks[i].float() / 255.0

    def weights(self, i: int) -> torch.Tensor | None:
        return None if self.pixel_weights is None else self.pixel_weights[i].float() / 255.0


class _DiskPixels(_Pixels):
    def __init__(self, subject: Subject, indices: np.ndarray, width: int, height: int, weighted: bool = False):
        self.subject, self.indices, self.size, self.weighted = subject, indices, (width, height), weighted

    def __len__(self) -> int:
        return len(self.indices)

    def get(self, i: int) -> tuple[torch.Tensor, torch.Tensor]:
        img, mask = _read(self.subject, int(self.indices[i]), self.size)
        return torch.from_numpy(img).float() / 255.0, torch.from_numpy(mask).float() / 255.0

    def weights(self, i: int) -> torch.Tensor | None:
        if not self.weighted:
            return None
        return torch.from_numpy(_read_weights(self.subject, int(self.indices[i]), self.size)).float() / 255.0


class _JoinedPixels(_Pixels):
    def __init__(self, first: _Pixels, second: _Pixels):
        self.first, self.second = first, second

    def __len__(self) -> int:
        return len(self.first) + len(self.second)

    def get(self, i: int) -> tuple[torch.Tensor, torch.Tensor]:
        n = len(self.first)
        return self.first.get(i) if i < n else self.second.get(i - n)

    def weights(self, i: int) -> torch.Tensor | None:
        n = len(self.first)
        return self.first.weights(i) if i < n else self.second.weights(i - n)


def _weights_path(subject: Subject, i: int):
    return subject.root / WEIGHTS_DIR / f"{subject.frame_names[i]}.png"


def _read_weights(subject: Subject, i: int, size: tuple[int, int]) -> np.ndarray:
    """Frame i's per-pixel loss weights resized to ``size`` (W, H) -> uint8 [H, W]."""
    from trioman.runtime.formats import FormatError
    from trioman.runtime.image_io import read_png

    path = _weights_path(subject, i)
    try:
        w = read_png(path, mode="gray")
    except (FileNotFoundError, ValueError) as err:
        raise FormatError(f"{path}: {'missing file' if isinstance(err, FileNotFoundError) else err} (the subject's "
                          f"{WEIGHTS_DIR}/ folder holds per-pixel weights for every frame or for none)") from None
    if w.shape != (subject.height, subject.width):
        raise FormatError(f"{path}: size {w.shape[1]}x{w.shape[0]} (W x H) does not match the subject's "
                          f"{subject.width}x{subject.height}")
    if size != (subject.width, subject.height):
        w = cv2.resize(w, size, interpolation=cv2.INTER_AREA)
    return np.rint(w * 255.0).astype(np.uint8)


def _read(subject: Subject, i: int, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Frame i resized to ``size`` (W, H) -> uint8 image [H, W, 3], uint8 mask [H, W]."""
    img, mask = subject.image(i), subject.mask(i)
    if size != (subject.width, subject.height):
        img = cv2.resize(img, size, interpolation=cv2.INTER_AREA)
        mask = cv2.resize(mask, size, interpolation=cv2.INTER_AREA)
    return np.rint(img * 255.0).astype(np.uint8), np.rint(mask * 255.0).astype(np.uint8)


@dataclass(frozen=True, eq=False)
class FrameSet:
    indices: np.ndarray  # [F] frame indices in the subject
    pixels: _Pixels  # images (premultiplied colour on black) and masks, by position in the set
    poses: torch.Tensor  # [F, J, 3]
    trans: torch.Tensor  # [F, 3]
    K: torch.Tensor  # [F, 3, 3] for the (resized) images
    viewmat: torch.Tensor  # [F, 4, 4]
    height: int
    width: int
    weights: np.ndarray | None = None  # [F] photometric loss weight per frame; None = 1 for every frame

    def __len__(self) -> int:
        return len(self.indices)

    def image(self, i: int) -> torch.Tensor:
        """[H, W, 3] float32 premultiplied colour on black."""
        return self.pixels.get(i)[0]

    def mask(self, i: int) -> torch.Tensor:
        """[H, W] float32."""
        return self.pixels.get(i)[1]

    def sample(self, i: int) -> dict:
        """Frame i as the training step takes it: images/masks/poses/trans/K/viewmat and its loss weight."""
        image, mask = self.pixels.get(i)
        fields = {k: getattr(self, k)[i] for k in ("poses", "trans", "K", "viewmat")}
        pixel_weights = self.pixels.weights(i)
        return {"images": image, "masks": mask, **fields, "weight": 1.0 if self.weights is None else float(self.weights[i]),
                **({} if pixel_weights is None else {"pixel_weights": pixel_weights})}


def load_frames(subject: Subject, split: str | None, scale: float = 1.0, stride: int = 1,
                in_memory_bytes: int = IN_MEMORY_BYTES) -> FrameSet:
    """Every ``stride``-th frame of ``split`` (train, test or None for all), resized by ``scale``: held as
    uint8 when the set takes at most ``in_memory_bytes`` (image + mask), else read from disk per draw.
    A subject folder with ``weights/`` (trioman augment's aligned pseudo-GT) gives every frame per-pixel loss
    weights (``FrameSet.sample``'s ``pixel_weights``)."""
    idx = subject.indices(split)[::stride]
    if len(idx) == 0:
        raise ValueError(f"split: subject {subject.root} has no {split!r} frames")
    W, H = max(1, round(subject.width * scale)), max(1, round(subject.height * scale))
    weighted = (subject.root / WEIGHTS_DIR).is_dir()
    if len(idx) * H * W * (5 if weighted else 4) <= in_memory_bytes:
        images, masks = np.empty((len(idx), H, W, 3), np.uint8), np.empty((len(idx), H, W), np.uint8)
        weights = np.empty((len(idx), H, W), np.uint8) if weighted else None
        for k, i in enumerate(idx):
            images[k], masks[k] = _read(subject, int(i), (W, H))
            if weights is not None:
                weights[k] = _read_weights(subject, int(i), (W, H))
        pixels: _Pixels = _MemoryPixels(images, masks, weights)
    else:
        pixels = _DiskPixels(subject, idx, W, H, weighted)
    K = subject.K[idx].astype(np.float64).copy()
    K[:, 0] *= W / subject.width  # continuous pixel coordinates scale with the image
    K[:, 1] *= H / subject.height
    return FrameSet(
        indices=idx,
        pixels=pixels,
        poses=torch.from_numpy(np.array(subject.poses[idx], dtype=np.float32)),
        trans=torch.from_numpy(np.array(subject.trans[idx], dtype=np.float32)),
        K=torch.from_numpy(K.astype(np.float32)),
        viewmat=torch.from_numpy(np.array(subject.viewmat[idx], dtype=np.float32)),
        height=H,
        width=W,
    )


def join_frames(frames: FrameSet, extra: FrameSet, extra_weight: float = 1.0) -> FrameSet:
    """``frames`` then ``extra`` (e.g. pseudo-GT frames of ``trioman augment``), the extra ones weighted by
    ``extra_weight``. ``indices`` keep each frame's index in its own subject. Same image size required."""
    if (extra.height, extra.width) != (frames.height, frames.width):
        raise ValueError(f"extra_frames: images are {extra.width}x{extra.height} (W x H) after scaling, "
                         f"but the subject's are {frames.width}x{frames.height}")
    ones = np.ones(len(frames)) if frames.weights is None else frames.weights
    weights = np.concatenate([ones, np.full(len(extra), float(extra_weight))])
    cat = {name: torch.cat([getattr(frames, name), getattr(extra, name)]) for name in ("poses", "trans", "K", "viewmat")}
    return FrameSet(indices=np.concatenate([frames.indices, extra.indices]), weights=weights,
                    pixels=_JoinedPixels(frames.pixels, extra.pixels), height=frames.height, width=frames.width, **cat)
