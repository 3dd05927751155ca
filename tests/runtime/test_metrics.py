"""numpy PSNR (trioman.runtime.metrics), the twin of the torch one."""

from __future__ import annotations

import numpy as np
import pytest

from trioman.runtime.metrics import PSNR_MAX_DB, psnr


def test_psnr_per_image_and_capped():
    rng = np.random.default_rng(0)
    a = rng.random((3, 8, 9, 3)).astype(np.float32)
    b = np.clip(a + rng.normal(0, 0.05, a.shape), 0, 1).astype(np.float32)
    mse = ((a.astype(np.float64) - b) ** 2).reshape(3, -1).mean(1)
    np.testing.assert_allclose(psnr(a, b), 10 * np.log10(1 / mse), rtol=1e-12)
    assert np.array_equal(psnr(a, a.copy()), np.full(3, PSNR_MAX_DB))


def test_psnr_matches_torch():
    torch = pytest.importorskip("torch")
    from trioman.toolkit.metrics import psnr as psnr_torch

    rng = np.random.default_rng(1)
    a, b = rng.random((2, 3, 6, 7)), rng.random((2, 3, 6, 7))
    np.testing.assert_allclose(psnr(a, b), psnr_torch(torch.from_numpy(a), torch.from_numpy(b)).numpy(), rtol=1e-12)


def test_psnr_shape_mismatch_is_an_error():
    with pytest.raises(ValueError, match="same shape"):
        psnr(np.zeros((2, 4, 4)), np.zeros((2, 4, 5)))
