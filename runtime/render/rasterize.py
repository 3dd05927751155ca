"""Tile rasterizer for 3D Gaussians in numpy (gsplat's semantics, DESIGN.md; no torch).

Semantics, per pixel with centre (j + 0.5, i + 0.5), visible Gaussians front to back by centre depth
(ties by index), each only within its radius box (:mod:`.tiles`):
sigma = 0.5 (A dx^2 + C dy^2) + B dx dy, alpha = min(0.99, o exp(-sigma)), skipped if < 1/255;
next_T = T (1 - alpha); stop, that Gaussian excluded, when next_T <= 1e-4; else w = alpha T, T = next_T.
Outputs: rgb = sum w c + T background, alpha = 1 - T, and depth = sum w z, the alpha-weighted SUM of
camera depths, NOT normalised (depth / alpha is the expected depth of the covered part).

Pipeline. :func:`~.projection.project` (float64, O(N) cheap culls, covariances for the survivors)
-> per-tile depth-sorted lists of (tile, Gaussian) pairs (:func:`~.tiles.bin_gaussians`) -> dense
evaluation of blocks [kb, tiles, s^2] (Gaussian, tile, pixel; the list axis outermost, so the running
product over it is kb vectorised multiplies): chunks of tiles sorted by list length, each walked
along the lists in blocks of kb Gaussians that carry the per-pixel T. Per block, each pair's
(u0, a, b, v0, c) (:func:`_block_alpha`, anchored at the tile centre in float64) become the pixels'
u, v by one matrix product each. A block holds at most ``chunk_elements`` pixel-Gaussian entries,
which bounds peak memory independently of N and of the image size; a tile leaves the walk once all
its pixels have stopped.

Precision. alpha, T and the colour sums are float32. T is a sequential float32 product, exactly the
stop test's ``T * (1 - alpha) <= 1e-4`` on float32 values. The quadratic form is evaluated in
Cholesky form, sigma = u^2 + v^2 with u, v anchored at each tile's centre in float64, so float32
pixels stay accurate for extreme and far-off-centre Gaussians.

Tile size. The dense cost is pairs x s^2, the binning cost grows with pairs. The avatar's Gaussians
are small (radius boxes ~9 px at 256 x 256) and its background pixels never stop, so tiles rarely
leave the walk early and the dense cost dominates: 4 x 4 tiles (``DEFAULT_TILE``) render the default
avatar at 256 x 256 in about 35 ms against 39 ms for 8 x 8 and 90 ms for 16 x 16 (2-core x86_64,
``trioman bench render`` has the current numbers). The result does not depend on the tile size.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from trioman.runtime.render.projection import (
    ALPHA_THRESHOLD,
    MAX_ALPHA,
    TRANSMITTANCE_THRESHOLD,
    check_inputs,
    project,
)
from trioman.runtime.render.tiles import bin_gaussians

DEFAULT_TILE = 4  # tile side in pixels (module doc)
DEFAULT_CHUNK_ELEMENTS = 1 << 16  # pixel x Gaussian entries per dense block (256 KiB per float32 array)
KB_MIN = 8  # shortest block along the lists

_F32 = np.float32
_THR_A32 = _F32(ALPHA_THRESHOLD)
_THR_T32 = _F32(TRANSMITTANCE_THRESHOLD)
_LOG_ZERO = -1e30  # log opacity of the padding Gaussian


class RenderOutput(NamedTuple):
    rgb: np.ndarray  # [H, W, 3] float32
    alpha: np.ndarray  # [H, W] float32
    depth: np.ndarray  # [H, W] float32, sum of w_i z_i (not normalised)


def _gaussian_table(p, opacities, colors) -> tuple[np.ndarray, np.ndarray]:
    """Per projected Gaussian: float64 [M + 1, 5] mean2d x, y, Cholesky a, b, c scaled by sqrt(1/2),
    and float32 [M + 1, 5] log o, rgb, z; row M is a padding Gaussian that is transparent everywhere."""
    m = len(p.ids)
    gq = np.zeros((m + 1, 5))
    gq[:m, 0:2] = p.means2d
    gq[:m, 2:5] = p.chol * np.sqrt(0.5)
    gf = np.zeros((m + 1, 5), dtype=_F32)
    gf[:m, 0] = np.log(opacities[p.ids].astype(np.float64))
    gf[:m, 1:4] = colors[p.ids]
    gf[:m, 4] = p.depths
    gf[m, 0] = _LOG_ZERO
    return gq, gf


def _offset_bases(s: int) -> tuple[np.ndarray, np.ndarray]:
    """(u0, a, b) @ B_u = u and (v0, c) @ B_v = v at the s^2 pixels of a tile (pixel = row s + col):
    u = u0 + a L_col + b L_row, v = v0 + c L_row, with L_l = l - (s - 1) / 2 the offset of pixel row or
    column l from the tile centre. -> B_u [3, s^2], B_v [2, s^2]."""
    L = np.arange(s) - (s - 1) / 2
    L_col, L_row, ones = np.tile(L, s), np.repeat(L, s), np.ones(s * s)
    return np.stack([ones, L_col, L_row]).astype(_F32), np.stack([ones, L_row]).astype(_F32)


def _block_alpha(Q: np.ndarray, logo: np.ndarray, centre: np.ndarray,
                 bases: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """Q [n, 5] (float64 Gaussian-table rows of n pairs), logo [n, 1] float32 log opacities, centre [n, 2] pixel coordinates of their tiles'
    centres -> alpha [n, s^2] = min(0.99, o exp(-sigma)), 0 where skipped (< 1/255).

    sigma = u^2 + v^2 in Cholesky form anchored at the tile centre: (u0, v0) = (a dx + b dy, c dy) with
    (dx, dy) = centre - mean2d in float64, then the pixels' u, v from :func:`_offset_bases`. No box test
    is needed here: the radius box circumscribes the ellipse where alpha >= 1/255 (:mod:`.tiles`), so
    every pixel outside the box is skipped anyway."""
    d = centre - Q[:, 0:2]
    coef = np.empty((len(Q), 5), dtype=_F32)
    coef[:, 0] = Q[:, 2] * d[:, 0] + Q[:, 3] * d[:, 1]
    coef[:, 1:3] = Q[:, 2:4]
    coef[:, 3] = Q[:, 4] * d[:, 1]
    coef[:, 4] = Q[:, 4]
    G = np.square(coef[:, :3] @ bases[0])  # u^2 [n, s^2]
    v = coef[:, 3:] @ bases[1]
    G += np.square(v, out=v)
    np.subtract(logo, G, out=G)  # log o - sigma
    np.exp(G, out=G)
    np.minimum(G, MAX_ALPHA, out=G)
    G[G < _THR_A32] = 0.0  # skip alpha < 1/255
    return G


def _composite(gq, gf, bins, inside, s: int, chunk_elements: int):
    """Front-to-back compositing of every tile. gq: :func:`_gaussian_table`; inside [T, s^2] bool
    (pixel within the image). -> color [T, 4, s^2] (sum w c, sum w z) and T_final [T, s^2], float32."""
    tile_start, tile_count = bins.tile_start, bins.tile_count
    pair_gauss = np.append(bins.pair_gauss, len(gq) - 1).astype(np.intp)  # pair P: the padding Gaussian
    n_pairs = len(bins.pair_gauss)
    n_tiles = len(tile_count)
    ty, tx = np.divmod(np.arange(n_tiles), bins.tiles_x)
    centres = np.stack([tx, ty], 1) * s + s / 2
    bases = _offset_bases(s)
    color = np.zeros((n_tiles, 4, s * s), dtype=_F32)
    T_final = np.ones((n_tiles, s * s), dtype=_F32)
    order = np.argsort(-tile_count, kind="stable")[:np.count_nonzero(tile_count)]
    per = max(1, chunk_elements // (s * s * KB_MIN))
    for c0 in range(0, len(order), per):
        tiles = order[c0:c0 + per]
        counts = tile_count[tiles]
        T = inside[tiles].astype(_F32)  # T after the last included Gaussian
        alive = inside[tiles].copy()  # until a pixel stops (False outside the image)
        acc = np.zeros((len(tiles), 4, s * s), dtype=_F32)
        local = np.arange(len(tiles))
        k0 = 0
        while len(local):
            ta = len(local)
            kb = int(min(max(KB_MIN, chunk_elements // (ta * s * s)), counts[local[0]] - k0))
            t = tiles[local]
            k = np.arange(k0, k0 + kb)[:, None]
            gi = np.take(pair_gauss, np.where(k < counts[local], tile_start[t] + k, n_pairs))
            gi = gi.reshape(-1)
            Q = np.take(gq, gi, axis=0)  # [kb ta, 5]
            F = np.take(gf, gi, axis=0)  # [kb ta, 5]
            cen = np.broadcast_to(centres[t], (kb, ta, 2)).reshape(-1, 2)
            alpha = _block_alpha(Q, F[:, :1], cen, bases).reshape(kb, ta, s * s)
            live = alive[local]
            P = np.empty((kb + 1, ta, s * s), dtype=_F32)  # T before each Gaussian, then after the last
            np.multiply(T[local], live, out=P[0])
            onem = np.subtract(_F32(1.0), alpha)
            for i in range(kb):
                np.multiply(P[i], onem[i], out=P[i + 1])
            incl = P[1:] > _THR_T32  # not stopped (a prefix of the block)
            w = np.multiply(alpha, P[:-1], out=alpha)
            w *= incl
            feats = F[:, 1:].reshape(kb, ta, 4)
            acc[local] += np.matmul(feats.transpose(1, 2, 0), w.transpose(1, 0, 2))
            # T where a pixel stopped in this block: P at its number of included Gaussians
            T_new = P[kb].copy()
            stopped = np.flatnonzero(live & ~incl[-1])
            n = np.count_nonzero(incl.reshape(kb, -1)[:, stopped], axis=0)
            T_new.reshape(-1)[stopped] = P.reshape(kb + 1, -1)[n, stopped]
            T[local] = np.where(live, T_new, T[local])
            alive[local] = live & incl[-1]
            k0 += kb
            local = local[(counts[local] > k0) & alive[local].any(1)]
        color[tiles] = acc
        T_final[tiles] = T
    return color, T_final


def rasterize(
    means: np.ndarray,  # [N, 3]
    quats: np.ndarray,  # [N, 4] wxyz, normalised inside (zero = identity)
    scales: np.ndarray,  # [N, 3] activated, metres
    opacities: np.ndarray,  # [N] in [0, 1]
    colors: np.ndarray,  # [N, 3]
    viewmat: np.ndarray,  # [4, 4] world -> camera (OpenCV)
    K: np.ndarray,  # [3, 3]
    width: int,
    height: int,
    background: np.ndarray | None = None,  # [3]; None: black
    near_plane: float = 0.01,
    far_plane: float = 1e10,
    *,
    tile_size: int = DEFAULT_TILE,
    chunk_elements: int = DEFAULT_CHUNK_ELEMENTS,
) -> RenderOutput:
    """Render Gaussians -> RenderOutput(rgb [H, W, 3], alpha [H, W], depth [H, W]), float32; see the
    module doc. ``depth`` is the alpha-weighted sum of camera depths, not normalised. N == 0 or nothing
    visible gives the background. ``tile_size`` is the tile side; ``chunk_elements`` bounds the dense
    pixel x Gaussian blocks (peak memory). Neither changes the result beyond float32 rounding of the
    colour sums."""
    arrays, width, height = check_inputs(means, quats, scales, opacities, colors, viewmat, K, width, height,
                                         background, near_plane, far_plane)
    means, quats, scales, opacities, colors, viewmat, K, background = arrays
    if isinstance(tile_size, bool) or not isinstance(tile_size, int) or not 1 <= tile_size <= 64:
        raise ValueError(f"tile_size: must be an int in [1, 64], got {tile_size!r}")
    if isinstance(chunk_elements, bool) or not isinstance(chunk_elements, int) or chunk_elements < 1:
        raise ValueError(f"chunk_elements: must be an int >= 1, got {chunk_elements!r}")
    bg = np.zeros(3, dtype=_F32) if background is None else background.astype(_F32)
    p = project(means, quats, scales, opacities, viewmat, K, width, height, near_plane, far_plane)
    if len(p.ids) == 0:
        zeros = np.zeros((height, width), dtype=_F32)
        return RenderOutput(np.broadcast_to(bg, (height, width, 3)).copy(), zeros, zeros.copy())
    s = tile_size
    bins = bin_gaussians(p.means2d, p.radii, p.depths, width, height, s, p.chol, opacities[p.ids])
    li = np.arange(s)
    ty, tx = np.divmod(np.arange(bins.tiles_x * bins.tiles_y), bins.tiles_x)
    inside = ((ty[:, None, None] * s + li[:, None] < height) & (tx[:, None, None] * s + li < width)).reshape(-1, s * s)
    color, T_final = _composite(*_gaussian_table(p, opacities, colors), bins, inside, s, chunk_elements)

    def to_image(x):  # [T, C, s^2] -> [H, W, C]
        img = x.reshape(bins.tiles_y, bins.tiles_x, x.shape[1], s, s).transpose(0, 3, 1, 4, 2)
        return img.reshape(bins.tiles_y * s, bins.tiles_x * s, x.shape[1])[:height, :width]

    color = to_image(color)
    T = to_image(T_final[:, None])
    rgb = color[..., :3] + T * bg
    return RenderOutput(np.ascontiguousarray(rgb), np.ascontiguousarray(1.0 - T[..., 0]),
                        np.ascontiguousarray(color[..., 3]))
