"""The rasterizer timings, from an installed package: the float64 oracle is part of it."""

from __future__ import annotations

import pytest

torch = pytest.importorskip("torch")

from trioman.bench.raster import bench_rasterizer  # noqa: E402


def test_bench_rasterizer_times_every_implementation_with_the_oracle():
    g = torch.Generator().manual_seed(0)
    n = 6
    gaussians = (torch.randn(n, 3, generator=g) * 0.2, torch.randn(n, 4, generator=g), torch.full((n, 3), 0.1),
                 torch.full((n,), 0.8), torch.rand(n, 3, generator=g))
    viewmat = torch.eye(4)
    viewmat[2, 3] = 3.0
    K = torch.tensor([[20.0, 0.0, 8.0], [0.0, 20.0, 8.0], [0.0, 0.0, 1.0]])
    (row,) = bench_rasterizer(gaussians, viewmat, K, sizes=(16,), repeats=1)
    keys = ("tiled_fwd_s", "tiled_fwd_bwd_s", "dense_fwd_s", "dense_fwd_bwd_s", "oracle_fwd_s")
    assert row["size"] == 16 and row["gaussians"] == n and all(row[k] > 0 for k in keys)
