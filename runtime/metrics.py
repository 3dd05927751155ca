"""Image metrics in numpy: PSNR. The numpy twin of :mod:`trioman.toolkit.metrics` (same name, same cap)."""

from __future__ import annotations

import numpy as np

PSNR_MAX_DB = 100.0  # PSNR of (near-)identical images: the MSE is floored at 10^-10 instead of giving +inf
MSE_FLOOR = 10.0 ** (-PSNR_MAX_DB / 10.0)


def psnr(pred: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """Peak signal-to-noise ratio in dB with data range 1, one value per image, computed in float64.

    pred, gt: [B, ...] (any image layout, the same for both) -> [B]. The MSE is floored at
    ``MSE_FLOOR``, so identical images give ``PSNR_MAX_DB``.
    """
    pred, gt = np.asarray(pred), np.asarray(gt)
    if pred.shape != gt.shape or pred.ndim < 2:
        raise ValueError(f"psnr: expected two arrays [B, ...] of the same shape, got {list(pred.shape)} and {list(gt.shape)}")
    diff = pred.astype(np.float64) - gt.astype(np.float64)
    mse = np.mean(diff * diff, axis=tuple(range(1, diff.ndim)))
    return 10.0 * np.log10(1.0 / np.maximum(mse, MSE_FLOOR))
