"""Tile binning: which Gaussians each square tile (``tile`` pixels a side) sees, front to back.

The rule (radius box, tile-ellipse culling, depth order): docs/design.md, "How the renderers compute it".
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

ELLIPSE_MARGIN = 1e-3  # relative widening of the squared Mahalanobis bound (rounding is ~1e-6)


class Bins(NamedTuple):
    """Per-tile lists of (tile, Gaussian) pairs; the same fields as the torch twin's
    (:class:`trioman.toolkit.render.tiles.Bins`)."""

    tiles_x: int
    tiles_y: int
    pair_gauss: np.ndarray  # [P] int64 projected-Gaussian index per (tile, Gaussian) pair; by tile, front to back
    pair_tile: np.ndarray  # [P] int32 tile id (ty * tiles_x + tx) of each pair
    tile_start: np.ndarray  # [T] int64 first pair of each tile
    tile_count: np.ndarray  # [T] int64 pairs per tile


def _ellipse_columns(mx, my, a, b, c, e2, y0, y1):
    """Pixel-centre x-range [x_lo, x_hi] of the ellipse (a dx + b dy)^2 + (c dy)^2 <= e2 over the band
    of pixel-centre rows y in [y0, y1] (empty band: x_lo > x_hi). All [R] float64.

    x(dy) = mx + (-b dy -+ sqrt(e2 - (c dy)^2)) / a; its left edge is convex in dy and the right edge
    concave, so each extreme over the band is at the clamp of the unconstrained extreme's dy,
    -+ sqrt(e2) b / (c sqrt(b^2 + c^2)) (the ellipse's leftmost / rightmost points)."""
    ry = np.sqrt(e2) / c  # the ellipse's half-height
    lo = np.maximum(y0 - my, -ry)
    hi = np.minimum(y1 - my, ry)
    dy_ext = np.sqrt(e2) * b / (c * np.sqrt(b * b + c * c))
    out = []
    for sign in (1.0, -1.0):  # left edge, then right edge
        dy = np.minimum(np.maximum(sign * dy_ext, lo), hi)
        half = np.sqrt(np.maximum(e2 - np.square(c * dy), 0.0))
        out.append(mx + (-b * dy - sign * half) / a)
    x_lo, x_hi = out
    x_hi = np.where(lo <= hi, x_hi, -np.inf)
    return x_lo, x_hi


def bin_gaussians(means2d: np.ndarray, radii: np.ndarray, depths: np.ndarray, width: int, height: int,
                  tile: int, chol: np.ndarray | None = None, opacities: np.ndarray | None = None) -> Bins:
    """means2d [M, 2], radii [M, 2] (whole numbers), depths [M] -> per-tile depth-sorted lists.
    chol [M, 3] (a, b, c) and opacities [M] (float): also cull tiles the alpha >= 1/255 ellipse misses."""
    tx_n, ty_n = -(-width // tile), -(-height // tile)
    n_tiles = tx_n * ty_n
    # pixel column / row ranges of the box (centres j + 0.5 within [m - r, m + r]), clipped to the image
    lo = np.maximum(np.ceil(means2d - radii - 0.5), 0.0)
    hi = np.minimum(np.floor(means2d + radii - 0.5), [width - 1, height - 1])
    ok = (lo <= hi).all(-1)
    t_lo = lo.astype(np.int32) // tile
    t_hi = np.maximum(hi, 0).astype(np.int32) // tile
    # front to back: emit pairs in depth order, then a stable sort by tile keeps that order
    order = np.argsort(depths, kind="stable")
    order = order[ok[order]]
    # (Gaussian, tile row) rows, in depth order then by tile row
    nr = (t_hi[order, 1] - t_lo[order, 1] + 1)
    rg = np.repeat(order, nr)
    tr = np.arange(len(rg), dtype=np.int32) - np.repeat((np.cumsum(nr) - nr).astype(np.int32), nr)
    tr += t_lo[rg, 1]
    c0, c1 = t_lo[rg, 0], t_hi[rg, 0]
    if chol is not None:
        a, b, c = (np.take(chol[:, k], rg) for k in range(3))
        with np.errstate(divide="ignore"):
            e2 = 2.0 * np.log(255.0 * np.take(np.asarray(opacities, dtype=np.float64), rg))
        e2 = np.maximum(e2, 0.0) * (1.0 + ELLIPSE_MARGIN) + ELLIPSE_MARGIN
        y0 = np.maximum(tr * tile, 0) + 0.5
        y1 = np.minimum(tr * tile + tile, height) - 0.5
        x_lo, x_hi = _ellipse_columns(np.take(means2d[:, 0], rg), np.take(means2d[:, 1], rg), a, b, c, e2, y0, y1)
        with np.errstate(invalid="ignore"):
            j_lo = np.ceil(x_lo - 0.5)
            j_hi = np.floor(x_hi - 0.5)
        keep = (j_lo <= j_hi) & (j_hi >= 0) & (j_lo <= width - 1)
        c0 = np.maximum(c0, np.minimum(np.maximum(j_lo, 0), width - 1).astype(np.int32) // tile)
        c1 = np.minimum(c1, np.minimum(np.maximum(j_hi, 0), width - 1).astype(np.int32) // tile)
        nc = np.where(keep, np.maximum(c1 - c0 + 1, 0), 0)
    else:
        nc = c1 - c0 + 1
    # (Gaussian, tile) pairs
    g = np.repeat(rg, nc)
    base = tr * tx_n + c0 - (np.cumsum(nc) - nc).astype(np.int32)  # tile id of pair k: base + k
    tile_id = np.repeat(base, nc) + np.arange(len(g), dtype=np.int32)
    perm = np.argsort(tile_id.astype(np.uint16) if n_tiles <= 1 << 16 else tile_id, kind="stable")
    tile_count = np.bincount(tile_id, minlength=n_tiles)
    pair_tile = np.repeat(np.arange(n_tiles, dtype=np.int32), tile_count)  # sorted by tile: the ids in order
    return Bins(tx_n, ty_n, np.take(g, perm), pair_tile, np.cumsum(tile_count) - tile_count, tile_count)
