"""Tile binning: which Gaussians each square tile (``tile`` pixels a side) sees, front to back.

A Gaussian reaches the pixels whose centres lie in its closed radius box,
|j + 0.5 - x| <= r_x and |i + 0.5 - y| <= r_y (the rasterizer applies that test per pixel); a tile
lists every Gaussian whose box reaches one of its pixel centres. (Rounding at the box edge is
immaterial: the box circumscribes the ellipse where alpha >= 1/255, so alpha < 1/255 on its edge.)
Within a tile the list is sorted by centre depth, ties by index.
"""

from __future__ import annotations

from typing import NamedTuple

import torch

TILE = 16


class Bins(NamedTuple):
    """Per-tile lists of (tile, Gaussian) pairs; the same fields as the numpy twin's
    (:class:`trioman.runtime.render.tiles.Bins`)."""

    tiles_x: int
    tiles_y: int
    pair_gauss: torch.Tensor  # [P] int64 visible-Gaussian index per (tile, Gaussian) pair; by tile, front to back
    pair_tile: torch.Tensor  # [P] int32 tile id (ty * tiles_x + tx) of each pair
    tile_start: torch.Tensor  # [T] int64 first pair of each tile
    tile_count: torch.Tensor  # [T] int64 pairs per tile


def bin_gaussians(means2d: torch.Tensor, radii: torch.Tensor, depths: torch.Tensor, width: int, height: int,
                  tile: int = TILE) -> Bins:
    """means2d [M, 2], radii [M, 2] (whole numbers), depths [M] -> per-tile depth-sorted lists."""
    dev = means2d.device
    tx_n, ty_n = -(-width // tile), -(-height // tile)
    m = means2d.detach().to(torch.float64)
    r = radii.detach().to(torch.float64)
    # pixel column / row ranges of the box (centres j + 0.5 within [m - r, m + r]), clipped to the image
    lo = torch.ceil(m - r - 0.5)
    hi = torch.floor(m + r - 0.5)
    lim = torch.tensor([width - 1, height - 1], dtype=torch.float64, device=dev)
    lo = torch.maximum(lo, torch.zeros_like(lo))
    hi = torch.minimum(hi, lim)
    ok = (lo <= hi).all(-1)
    t_lo = torch.div(lo.clamp(min=0).to(torch.int64), tile, rounding_mode="floor")
    t_hi = torch.div(hi.clamp(min=0).to(torch.int64), tile, rounding_mode="floor")
    span = (t_hi - t_lo + 1) * ok[:, None]
    count = span[:, 0] * span[:, 1]
    # front to back: emit pairs in depth order, then a stable sort by tile keeps that order
    order = torch.sort(depths.detach(), stable=True).indices
    count_o = count[order]
    total = int(count_o.sum())
    g = torch.repeat_interleave(order, count_o, output_size=total)
    start = torch.cumsum(count_o, 0) - count_o
    k = torch.arange(total, device=dev) - torch.repeat_interleave(start, count_o, output_size=total)
    nx = span[g, 0]
    tx = t_lo[g, 0] + k % nx.clamp(min=1)
    ty = t_lo[g, 1] + torch.div(k, nx.clamp(min=1), rounding_mode="floor")
    tile_id = (ty * tx_n + tx).to(torch.int32)  # int32 sorts about twice as fast
    tile_sorted, perm = torch.sort(tile_id, stable=True)
    pair_gauss = g[perm]
    tile_count = torch.bincount(tile_sorted, minlength=tx_n * ty_n)
    tile_start = torch.cumsum(tile_count, 0) - tile_count
    return Bins(tx_n, ty_n, pair_gauss, tile_sorted, tile_start, tile_count)
