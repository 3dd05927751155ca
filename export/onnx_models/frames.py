"""Frames for calibration, parity and the int8 gates: triplet files or synthetic ones."""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple, Sequence

import numpy as np

from trioman.export.onnx_models.constants import REFINER_BATCH_PIXELS, REFINER_MAX_BATCH


class Frames(NamedTuple):
    """Float32 NHWC images in [0, 1] at the export size."""

    gt: np.ndarray  # I^T
    coarse: np.ndarray  # I_c^T
    normal: np.ndarray  # I_g^T
    reference: np.ndarray  # I^{T+k} (calibration) / the nearest-view training frame (gate)
    aligned: np.ndarray | None = None  # T's aligned reference, coarse where nothing was carried (warp* Refiners)

    @property
    def count(self) -> int:
        return len(self.gt)


def _resize(images: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    if tuple(images.shape[1:3]) == tuple(size):
        return np.ascontiguousarray(images, dtype=np.float32)
    import cv2

    H, W = size
    return np.stack([cv2.resize(np.ascontiguousarray(im, dtype=np.float32), (W, H), interpolation=cv2.INTER_AREA)
                     for im in images])


def _frames_at(t: Any, size: tuple[int, int]) -> Frames:
    return Frames(_resize(t.gt, size), _resize(t.coarse, size), _resize(t.normal, size), _resize(t.reference, size),
                  None if t.aligned is None else _resize(t.aligned, size))


def synthetic_frames(n: int, size: tuple[int, int], seed: int) -> Frames:
    """Random stand-ins for triplet frames: smooth colour textures (gt), a blurred, colour-shifted, noisy
    copy (coarse), a shifted copy (reference), another texture (normal) and the gt shifted by a pixel in
    the left half, the coarse copy in the right (aligned)."""
    import cv2

    rng = np.random.default_rng(seed)
    H, W = size

    def texture() -> np.ndarray:
        low = rng.random((max(2, H // 8), max(2, W // 8), 3), dtype=np.float32)
        return np.clip(cv2.resize(low, (W, H), interpolation=cv2.INTER_LINEAR), 0, 1)

    gt = np.stack([texture() for _ in range(n)])
    coarse = np.stack([cv2.blur(g, (5, 5)) for g in gt]) + 0.15 * (rng.random((n, 1, 1, 3), dtype=np.float32) - 0.5)
    coarse = np.clip(coarse + 0.03 * rng.standard_normal(gt.shape, dtype=np.float32), 0, 1)
    reference = np.roll(gt, (2, 2), axis=(1, 2))
    normal = np.stack([texture() for _ in range(n)])
    aligned = np.concatenate([np.roll(gt, (1, 1), axis=(1, 2))[:, :, : W // 2], coarse[:, :, W // 2:]], axis=2)
    return Frames(gt.astype(np.float32), coarse.astype(np.float32), normal, reference.astype(np.float32),
                  aligned.astype(np.float32))


@dataclass
class Data:
    """Calibration and gate frames at one size, and how they were obtained (for the report)."""

    calibration: Frames
    gate: Frames
    info: dict


def load_data(calibration: Sequence[str | os.PathLike] | None, size: tuple[int, int], *, calibration_frames: int = 32,
              gate_frames: int = 32, seed: int = 0, triplets: Any = None) -> Data:
    """Calibration frames (T, T+k pairs of the training split) and gate frames (the test split with
    nearest-view references when there is one, else other random frames) from triplet files, resized to
    ``size``; synthetic random frames when ``calibration`` is None or empty. ``triplets``: the files
    already loaded as a TripletSet (to load them once for both models)."""
    if not calibration:
        return Data(synthetic_frames(calibration_frames, size, seed), synthetic_frames(gate_frames, size, seed + 1),
                    {"source": "synthetic", "note": "no calibration triplets given: int8 calibration and gates used "
                     "synthetic random images, not real frames", "calibration_frames": calibration_frames,
                     "gate_frames": gate_frames})
    from trioman.toolkit.corpus.triplets import TripletSet

    paths = [str(Path(p)) for p in calibration]
    data = triplets if triplets is not None else TripletSet.load(paths)
    rng = np.random.default_rng(seed)
    has_train, has_test = bool(np.any(data.split == "train")), bool(np.any(data.split == "test"))
    calib = data.sample(rng, calibration_frames, k_max=4, split="train" if has_train else None)
    if has_train and has_test:
        test = np.nonzero(data.split == "test")[0]
        pick = test[np.unique(np.linspace(0, len(test) - 1, min(gate_frames, len(test))).round().astype(int))]
        gate = data.take(pick, np.array([data.nearest_view(int(i)) for i in pick], dtype=np.int64))
        gate_split = "test"
    else:
        gate = data.sample(rng, gate_frames, k_max=4)
        gate_split = "all (no train/test split)"
    H0, W0 = data.gt.shape[1:3]
    return Data(_frames_at(calib, size), _frames_at(gate, size),
                {"source": "triplets", "files": paths, "frame_size": [int(H0), int(W0)],
                 "resized_to": list(size) if (H0, W0) != tuple(size) else None,
                 "calibration_frames": len(calib.gt), "calibration_split": "train" if has_train else "all",
                 "gate_frames": len(gate.gt), "gate_split": gate_split})


def triplet_size(calibration: Sequence[str | os.PathLike]) -> tuple[int, int]:
    """(H, W) of the first triplet file's frames, from its ``meta`` entry (the images are not read)."""
    from trioman.runtime.formats.common import FormatError

    path = Path(calibration[0])
    try:
        with np.load(path, allow_pickle=False) as archive:
            meta = json.loads(str(archive["meta"]))
        return int(meta["height"]), int(meta["width"])
    except FileNotFoundError:
        raise FormatError(f"{path}: missing file") from None
    except Exception as err:  # not an npz, no meta, malformed JSON, ...
        raise FormatError(f"{path}: not a triplet file with a 'meta' entry giving height and width "
                          f"({type(err).__name__}: {err})") from None


def nchw(x: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(x.transpose(0, 3, 1, 2), dtype=np.float32)


def refiner_frames_per_batch(size: tuple[int, int]) -> int:
    """Frames per Refiner batch at this (H, W): REFINER_BATCH_PIXELS and REFINER_MAX_BATCH."""
    return max(1, min(REFINER_MAX_BATCH, REFINER_BATCH_PIXELS // (size[0] * size[1])))
