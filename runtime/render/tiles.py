"""Tile binning: which Gaussians each square tile (``tile`` pixels a side) sees, front to back.

A Gaussian reaches the pixels whose centres lie in its closed radius box,
|j + 0.5 - x| <= r_x and |i + 0.5 - y| <= r_y (the rasterizer applies that test per pixel); a tile
lists every Gaussian whose box reaches one of its pixel centres. Within a tile the list is sorted by
centre depth, ties by index: pairs are emitted in depth order and a stable sort by tile id keeps it
(a radix sort on uint16 ids when there are at most 65536 tiles).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np


class Bins(NamedTuple):
    tiles_x: int
    tiles_y: int
    pair_gauss: np.ndarray  # [P] int64 projected-Gaussian index per (tile, Gaussian) pair; by tile, front to back
    tile_start: np.ndarray  # [T] int64 first pair of each tile
    tile_count: np.ndarray  # [T] int64 pairs per tile


def bin_gaussians(means2d: np.ndarray, radii: np.ndarray, depths: np.ndarray, width: int, height: int,
                  tile: int) -> Bins:
    """means2d [M, 2], radii [M, 2] (whole numbers), depths [M] -> per-tile depth-sorted lists."""
    tx_n, ty_n = -(-width // tile), -(-height // tile)
    # pixel column / row ranges of the box (centres j + 0.5 within [m - r, m + r]), clipped to the image
    lo = np.maximum(np.ceil(means2d - radii - 0.5), 0.0)
    hi = np.minimum(np.floor(means2d + radii - 0.5), [width - 1, height - 1])
    ok = (lo <= hi).all(-1)
    t_lo = lo.astype(np.int64) // tile
    span = (np.maximum(hi, 0).astype(np.int64) // tile - t_lo + 1) * ok[:, None]
    # front to back: emit pairs in depth order, then a stable sort by tile keeps that order
    order = np.argsort(depths, kind="stable")
    count = (span[:, 0] * span[:, 1])[order]
    g = np.repeat(order, count)
    k = np.arange(len(g)) - np.repeat(np.cumsum(count) - count, count)
    nx = np.maximum(span[g, 0], 1)
    row, col = np.divmod(k, nx)
    tile_id = (t_lo[g, 1] + row) * tx_n + t_lo[g, 0] + col
    perm = np.argsort(tile_id.astype(np.uint16 if tx_n * ty_n <= 1 << 16 else np.int64), kind="stable")
    tile_count = np.bincount(tile_id, minlength=tx_n * ty_n)
    return Bins(tx_n, ty_n, g[perm], np.cumsum(tile_count) - tile_count, tile_count)
