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


def _depth_order(depths: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """Indices [K] of the Gaussians where ``ok`` [M], by depth [M], ties by index. A quicksort, then the
    stable sort only when two depths are equal."""
    idx = np.flatnonzero(ok)
    d = np.take(depths, idx)
    order = np.argsort(d)
    ds = np.take(d, order)
    if np.any(ds[1:] == ds[:-1]):
        order = np.argsort(d, kind="stable")
    return np.take(idx, order)


def _ellipse_columns(mx, my, a, b, c, e2, rg, y0, y1) -> tuple[np.ndarray, np.ndarray]:
    """Pixel-centre x-range [x_lo, x_hi] of the ellipse (a dx + b dy)^2 + (c dy)^2 <= e2 over the band
    of pixel-centre rows y in [y0, y1]. mx, my, a, b, c, e2: [K] float64 per Gaussian; rg [R] intp: the
    Gaussian of each band; y0, y1 [R]. -> x_lo, x_hi [R] (NaN where the band misses the ellipse).

    x(dy) = mx - (b/a) dy -+ sqrt(e2 - (c dy)^2) / a; its left edge is convex in dy and the right edge
    concave, so each extreme over the band is at the clamp of the unconstrained extreme's dy,
    -+ sqrt(e2) b / (c sqrt(b^2 + c^2)) (the ellipse's leftmost / rightmost points)."""
    sq = np.sqrt(e2)
    ry = sq / c  # the ellipse's half-height
    per = [mx, my, ry, sq * b / (c * np.sqrt(b * b + c * c)), b / a, e2 / (a * a), np.square(c / a)]
    mx, my, ry, dy_ext, ba, e2a, ca2 = (np.take(x, rg) for x in per)
    lo = np.subtract(y0, my, out=y0)
    np.maximum(lo, -ry, out=lo)
    hi = np.subtract(y1, my, out=y1)
    np.minimum(hi, ry, out=hi)
    np.copyto(hi, np.nan, where=lo > hi)  # the band misses the ellipse
    out = []
    for sign in (-1.0, 1.0):  # left edge, then right edge
        dy = np.multiply(dy_ext, -sign)
        np.clip(dy, lo, hi, out=dy)
        half = np.square(dy)
        half *= ca2
        np.subtract(e2a, half, out=half)
        np.sqrt(np.maximum(half, 0.0, out=half), out=half)
        dy *= ba
        np.subtract(mx, dy, out=dy)
        half *= sign
        dy += half
        out.append(dy)
    return out[0], out[1]


def bin_gaussians(means2d: np.ndarray, radii: np.ndarray, depths: np.ndarray, width: int, height: int,
                  tile: int, chol: np.ndarray | None = None, opacities: np.ndarray | None = None) -> Bins:
    """means2d [2, M], radii [2, M] (whole numbers), depths [M] -> per-tile depth-sorted lists.
    chol [3, M] (a, b, c) and opacities [M] (float): also cull tiles the alpha >= 1/255 ellipse misses."""
    tx_n, ty_n = -(-width // tile), -(-height // tile)
    n_tiles = tx_n * ty_n
    # pixel column / row ranges of the box (centres j + 0.5 within [m - r, m + r]), clipped to the image
    lo = np.maximum(np.ceil(means2d - radii - 0.5), 0.0)
    hi = np.minimum(np.floor(means2d + radii - 0.5), [[width - 1], [height - 1]])
    # front to back: emit pairs in depth order, then a stable sort by tile keeps that order
    order = _depth_order(depths, (lo[0] <= hi[0]) & (lo[1] <= hi[1]))
    t_lo = np.take(lo, order, axis=1).astype(np.intp) // tile  # [2, K] tile ranges, in depth order
    t_hi = np.take(hi, order, axis=1).astype(np.intp) // tile
    # (Gaussian, tile row) rows, in depth order then by tile row
    # rg: each row's position in order (intp: numpy gathers convert other index types first)
    nr = t_hi[1] - t_lo[1] + 1
    rg = np.repeat(np.arange(len(order)), nr)
    tr = np.arange(len(rg)) - np.take(np.cumsum(nr) - nr - t_lo[1], rg)
    c0, c1 = np.take(t_lo[0], rg), np.take(t_hi[0], rg)
    if chol is not None:
        c0, c1 = _ellipse_tiles(means2d, chol, opacities, order, rg, tr, c0, c1, width, height, tile)
    nc = np.maximum(c1 - c0 + 1, 0)  # an ellipse that misses a row of its box covers none of its tiles
    # (Gaussian, tile) pairs
    pr = np.repeat(np.arange(len(rg)), nc)  # each pair's row
    g = np.take(order, np.take(rg, pr))
    base = tr * tx_n + c0 - (np.cumsum(nc) - nc)  # tile id of pair k: base + k
    tile_id = np.take(base, pr) + np.arange(len(g))
    perm = np.argsort(tile_id.astype(np.uint16) if n_tiles <= 1 << 16 else tile_id, kind="stable")
    tile_count = np.bincount(tile_id, minlength=n_tiles)
    pair_tile = np.repeat(np.arange(n_tiles, dtype=np.int32), tile_count)  # sorted by tile: the ids in order
    return Bins(tx_n, ty_n, np.take(g, perm), pair_tile, np.cumsum(tile_count) - tile_count, tile_count)


def _ellipse_tiles(means2d, chol, opacities, order, rg, tr, c0, c1, width: int, height: int,
                   tile: int) -> tuple[np.ndarray, np.ndarray]:
    """The tile columns [c0, c1] of each (Gaussian, tile row) row [R] narrowed to the tiles whose pixel
    centres the Gaussian's alpha >= 1/255 ellipse reaches (c1 = c0 - 1 where it reaches none). order [K]:
    the Gaussians; rg [R]: each row's position in order; tr [R]: its tile row."""
    per = [np.take(x, order) for x in (means2d[0], means2d[1], chol[0], chol[1], chol[2])]
    with np.errstate(divide="ignore"):
        e2 = 2.0 * np.log(255.0 * np.take(np.asarray(opacities, dtype=np.float64), order))
    e2 = np.maximum(e2, 0.0) * (1.0 + ELLIPSE_MARGIN) + ELLIPSE_MARGIN
    y0 = tr * float(tile)
    y1 = np.minimum(y0 + tile, height) - 0.5
    y0 += 0.5
    x_lo, x_hi = _ellipse_columns(*per, e2, rg, y0, y1)
    with np.errstate(invalid="ignore"):
        j_lo = np.ceil(x_lo - 0.5, out=x_lo)
        j_hi = np.floor(x_hi - 0.5, out=x_hi)
        miss = ~((j_lo <= j_hi) & (j_hi >= 0) & (j_lo <= width - 1))  # also where NaN
        c0 = np.maximum(c0, np.clip(j_lo, 0, width - 1, out=j_lo).astype(np.intp) // tile)
        c1 = np.minimum(c1, np.clip(j_hi, 0, width - 1, out=j_hi).astype(np.intp) // tile)
    np.copyto(c1, c0 - 1, where=miss)
    return c0, c1
