"""Tile rasterizer for 3D Gaussians in numpy (no torch): the runtime's renderer, ``rasterize``.

What it computes: docs/design.md, "Renderer semantics"; how (pipeline, precision, tile size): its
"How the renderers compute it".
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
from trioman.runtime.stages import stage

DEFAULT_TILE = 4  # tile side in pixels (docs/design.md, "How the renderers compute it")
DEFAULT_CHUNK_ELEMENTS = 1 << 16  # pixel x Gaussian entries per dense block (256 KiB per float32 array): blocks
# small enough that the [n, 3] @ [3, s^2] products stay on one BLAS thread (docs/findings.md, "Renderers")
KB_MIN = 8  # shortest block along the lists

_F32 = np.float32
_THR_A32 = _F32(ALPHA_THRESHOLD)
_THR_T32 = _F32(TRANSMITTANCE_THRESHOLD)
_MAX_A32 = _F32(MAX_ALPHA)
_LOG_ZERO = -1e30  # log opacity of the padding Gaussian


class RenderOutput(NamedTuple):
    rgb: np.ndarray  # [H, W, 3] float32
    alpha: np.ndarray  # [H, W] float32
    depth: np.ndarray  # [H, W] float32, sum of w_i z_i (not normalised)


class GaussTable(NamedTuple):
    """Per projected Gaussian, plus a padding Gaussian at row M (transparent everywhere), rows of at most
    32 bytes (numpy gathers them fastest): the Cholesky form (a, b, c) is scaled by sqrt(1/2), see
    :func:`_block_alpha`."""

    anchor: np.ndarray  # [M + 1, 4] float64 mean x, mean y, a, b
    conic: np.ndarray  # [M + 1, 8] float32 (slot u0), a, b, (slot v0), c, log o, 0, 0
    color: np.ndarray  # [M + 1, 4] float32 rgb, z


def _gauss_table(p, opacities: np.ndarray, colors: np.ndarray) -> GaussTable:
    """The :class:`GaussTable` of the projected Gaussians ``p``."""
    m = len(p.ids)
    abc = p.chol * np.sqrt(0.5)
    anchor = np.zeros((m + 1, 4))
    anchor[:m] = np.concatenate([p.means2d, abc[:2]]).T
    conic = np.zeros((m + 1, 8), dtype=_F32)
    conic[:m, 1:3] = abc[:2].T
    conic[:m, 4] = abc[2]
    o = np.take(opacities, p.ids)
    if not np.all(o == 1):  # log 1 = 0: the zeros stand
        conic[:m, 5] = np.log(o.astype(np.float64))
    conic[m, 5] = _LOG_ZERO
    color = np.zeros((m + 1, 4), dtype=_F32)
    color[:m, :3] = np.take(colors, p.ids, axis=0)
    color[:m, 3] = p.depths
    return GaussTable(anchor, conic, color)


def _block_table(gidx: np.ndarray, centres: np.ndarray, tab: GaussTable) -> tuple[np.ndarray, np.ndarray]:
    """The pairs [kb, ta] of a block (gidx: their Gaussians, row M = padding; centres [2, ta]: their
    tiles' centres) -> X [kb ta, 8] (u0, a, b, v0, c, log o, 0, 0) and C [kb ta, 4] (rgb, z), float32.

    The anchoring is float64, rounded to float32 once: (u0, v0) = (a dx + b dy, c dy) with
    (dx, dy) = tile centre - mean2d."""
    kb, ta = gidx.shape
    gidx = gidx.reshape(-1)
    A = np.take(tab.anchor, gidx, axis=0)
    X = np.take(tab.conic, gidx, axis=0)
    dx = np.subtract(centres[0], A[:, 0].reshape(kb, ta)).reshape(-1)
    dy = np.subtract(centres[1], A[:, 1].reshape(kb, ta)).reshape(-1)
    np.multiply(X[:, 4], dy, out=X[:, 3], casting="same_kind")  # v0 = c dy
    dx *= A[:, 2]
    dy *= A[:, 3]
    np.add(dx, dy, out=X[:, 0], casting="same_kind")  # u0 = a dx + b dy
    return X, np.take(tab.color, gidx, axis=0)


def _offset_bases(s: int) -> tuple[np.ndarray, np.ndarray]:
    """(u0, a, b) @ B_u = u and (v0, c) @ B_v = v at the s^2 pixels of a tile (pixel = row s + col):
    u = u0 + a L_col + b L_row, v = v0 + c L_row, with L_l = l - (s - 1) / 2 the offset of pixel row or
    column l from the tile centre. -> B_u [3, s^2], B_v [2, s^2]."""
    L = np.arange(s) - (s - 1) / 2
    L_col, L_row, ones = np.tile(L, s), np.repeat(L, s), np.ones(s * s)
    return np.stack([ones, L_col, L_row]).astype(_F32), np.stack([ones, L_row]).astype(_F32)


def _block_alpha(X: np.ndarray, bases: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """X [n, 8] (:func:`_block_table` of n pairs) -> alpha [n, s^2] =
    min(0.99, o exp(-sigma)), 0 where skipped (< 1/255), float32.

    sigma = u^2 + v^2 in Cholesky form anchored at the tile centre, the pixels' u, v from
    :func:`_offset_bases` (one small matrix product each). No box test is needed here: the radius box
    circumscribes the ellipse where alpha >= 1/255 (:mod:`.tiles`), so every pixel outside the box is
    skipped anyway."""
    G = np.square(X[:, 0:3] @ bases[0])  # u^2 [n, s^2]
    v = X[:, 3:5] @ bases[1]
    G += np.square(v, out=v)
    if X[:, 5].any():
        np.subtract(X[:, 5:6], G, out=G)  # log o - sigma
    else:  # every opacity is 1: log o - sigma = -sigma exactly, without the row broadcast
        np.negative(G, out=G)
    np.exp(G, out=G)
    keep = np.greater_equal(G, _THR_A32).view(np.uint8)  # skip alpha < 1/255 (decided before the cap,
    np.minimum(G, _MAX_A32, out=G)  # as the cap is above it), by a multiply: no branch per entry
    np.multiply(G, keep, out=G, casting="unsafe")
    return G


def _composite(tab: GaussTable, bins, s: int, chunk_elements: int):
    """Front-to-back compositing of every tile (tab: :func:`_gauss_table`) -> color [T, 4, s^2]
    (sum w c, sum w z) and T_final [T, s^2], float32. Every pixel of a tile is composited, those
    beyond the image's right and bottom edges too (they are cropped afterwards).

    Tiles go by decreasing list length in chunks; a chunk is walked along its lists in blocks
    [kb, ta, s^2] (list position, tile, pixel), each block's pair values built when it is reached
    (:func:`_block_table`), so the pairs behind stopped tiles cost nothing. Per block the running
    product over the kb positions is kb vectorised float32 multiplies from each pixel's T (0 once
    stopped), so P[i] is exactly the sequential T before position i. The state of the tiles still in
    the walk (T, T at the stop, colour sums) is kept compact; a tile whose list is done or whose pixels
    have all stopped is written out."""
    tile_start, tile_count = bins.tile_start, bins.tile_count
    pair_gauss = np.append(bins.pair_gauss, len(tab.anchor) - 1)  # position P: the padding Gaussian
    n_pairs = len(bins.pair_gauss)
    n_tiles = len(tile_count)
    bases = _offset_bases(s)
    s2 = s * s
    color = np.zeros((n_tiles, 4, s2), dtype=_F32)
    T_final = np.ones((n_tiles, s2), dtype=_F32)
    order = np.argsort(-tile_count, kind="stable")[:np.count_nonzero(tile_count)]
    per = max(1, chunk_elements // (s2 * KB_MIN))
    for c0 in range(0, len(order), per):
        tiles = order[c0:c0 + per]  # the tiles still in the walk, longest list first
        counts = tile_count[tiles]
        starts = tile_start[tiles]
        T = np.ones((len(tiles), s2), dtype=_F32)  # T of live pixels; 0 once stopped
        T_stop = np.zeros_like(T)  # T at the stop of pixels that stopped
        acc = np.zeros((len(tiles), 4, s2), dtype=_F32)
        k0 = 0
        while True:
            ta = len(tiles)
            kb = int(min(max(KB_MIN, chunk_elements // (ta * s2)), counts[0] - k0))
            k = np.arange(k0, k0 + kb)[:, None]
            gidx = np.take(pair_gauss, np.where(k < counts, starts + k, n_pairs))  # [kb, ta]
            ty, tx = np.divmod(tiles, bins.tiles_x)
            X, C = _block_table(gidx, np.stack([tx * s + s / 2, ty * s + s / 2]), tab)
            alpha = _block_alpha(X, bases).reshape(kb, ta * s2)
            P = np.empty((kb + 1, ta * s2), dtype=_F32)  # T before each position, then after the last
            P[0] = T.reshape(-1)
            onem = np.subtract(_F32(1.0), alpha)
            for i in range(kb):
                np.multiply(P[i], onem[i], out=P[i + 1])
            incl = P[1:] > _THR_T32  # not stopped (a prefix of the block; all False once stopped)
            w = np.multiply(alpha, P[:-1], out=alpha)
            w *= incl
            acc += np.matmul(C.reshape(kb, ta, 4).transpose(1, 2, 0), w.reshape(kb, ta, s2).transpose(1, 0, 2))
            # pixels stopping in this block: T = P at their number of included positions
            go_on = incl[-1]
            stopping = np.flatnonzero((P[0] > 0.0) & ~go_on)
            if len(stopping):  # n = number of included positions (incl is a prefix)
                n = incl.view(np.uint8).sum(0, dtype=np.uint8 if kb < 256 else np.intp)
                T_stop.reshape(-1)[stopping] = P[n[stopping], stopping]
            T = np.multiply(P[kb], go_on).reshape(ta, s2)
            k0 += kb
            keep = (counts > k0) & go_on.reshape(ta, s2).any(1)
            if not keep.all():
                gone = ~keep
                done = tiles[gone]
                color[done] = acc[gone]
                T_final[done] = T[gone] + T_stop[gone]
                if not keep.any():
                    break
                tiles, counts, starts = tiles[keep], counts[keep], starts[keep]
                T, T_stop, acc = T[keep], T_stop[keep], acc[keep]
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
    extent: str = "opacity",
) -> RenderOutput:
    """Render Gaussians -> RenderOutput(rgb [H, W, 3], alpha [H, W], depth [H, W]), float32 (docs/design.md,
    "Renderer semantics"). ``depth`` is the alpha-weighted sum of camera depths, not normalised. N == 0 or
    nothing visible gives the background. ``tile_size`` is the tile side; ``chunk_elements`` bounds the dense
    pixel x Gaussian blocks (peak memory). Neither changes the result beyond float32 rounding of the
    colour sums. ``extent`` is the radius rule (:func:`~.projection.project`): "opacity" (exact, the
    default) bins each Gaussian to the tiles its alpha >= 1/255 ellipse touches; "3sigma" to the tiles
    of its 3-sigma box, gsplat's rule (faster for opaque Gaussians, cuts their faint tails)."""
    arrays, width, height = check_inputs(means, quats, scales, opacities, colors, viewmat, K, width, height,
                                         background, near_plane, far_plane)
    means, quats, scales, opacities, colors, viewmat, K, background = arrays
    if isinstance(tile_size, bool) or not isinstance(tile_size, int) or not 1 <= tile_size <= 64:
        raise ValueError(f"tile_size: must be an int in [1, 64], got {tile_size!r}")
    if isinstance(chunk_elements, bool) or not isinstance(chunk_elements, int) or chunk_elements < 1:
        raise ValueError(f"chunk_elements: must be an int >= 1, got {chunk_elements!r}")
    bg = np.zeros(3, dtype=_F32) if background is None else background.astype(_F32)
    with stage("projection"):
        p = project(means, quats, scales, opacities, viewmat, K, width, height, near_plane, far_plane, extent)
    if len(p.ids) == 0:
        zeros = np.zeros((height, width), dtype=_F32)
        return RenderOutput(np.broadcast_to(bg, (height, width, 3)).copy(), zeros, zeros.copy())
    s = tile_size
    ellipse = (p.chol, np.take(opacities, p.ids)) if extent == "opacity" else (None, None)
    with stage("tile binning"):
        bins = bin_gaussians(p.means2d, p.radii, p.depths, width, height, s, *ellipse)
    with stage("Gaussian table"):
        tab = _gauss_table(p, opacities, colors)
    with stage("compositing"):
        color, T_final = _composite(tab, bins, s, chunk_elements)
    with stage("image"):
        return _image(color, T_final, bins, s, width, height, bg)


def _image(color: np.ndarray, T_final: np.ndarray, bins, s: int, width: int, height: int,
           bg: np.ndarray) -> RenderOutput:
    """Per-tile color [T, 4, s^2] and T_final [T, s^2] -> the RenderOutput of the image."""
    # tiles -> images: [T, C, s^2] -> C planes [H, W] (contiguous copies), then rgb interleaved once
    ty, tx = bins.tiles_y, bins.tiles_x
    planes = np.empty((4, ty, s, tx, s), dtype=_F32)
    planes[:] = color.reshape(ty, tx, 4, s, s).transpose(2, 0, 3, 1, 4)
    planes = planes.reshape(4, ty * s, tx * s)[:, :height, :width]
    T = np.empty((ty, s, tx, s), dtype=_F32)
    T[:] = T_final.reshape(ty, tx, s, s).transpose(0, 2, 1, 3)
    T = T.reshape(ty * s, tx * s)[:height, :width]
    rgb = np.empty((height, width, 3), dtype=_F32)
    for k in range(3):
        rgb[..., k] = planes[k] + T * bg[k] if bg[k] != 0 else planes[k]
    return RenderOutput(rgb, 1.0 - T, np.ascontiguousarray(planes[3]))
