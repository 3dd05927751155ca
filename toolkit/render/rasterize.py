"""Differentiable tile rasterizer for 3D Gaussians on the CPU (torch): ``rasterize``, the training renderer.

What it computes: docs/design.md, "Renderer semantics"; how (pipeline, precision, the backward pass,
tile size): its "How the renderers compute it". The dense evaluation has two implementations: the torch
one (``_Raster``, the reference) and a C kernel (``raster_cpu.c`` through ``_NativeRaster``) with the same
semantics, used for float32 CPU renders when it builds.
"""

from __future__ import annotations

import bisect
import ctypes
import math
import os
from concurrent.futures import ThreadPoolExecutor
from typing import NamedTuple

import torch
import torch.nn.functional as F
from torch.autograd.function import once_differentiable

from trioman.runtime.stages import stage
from trioman.toolkit.render import native
from trioman.toolkit.render.projection import (
    ALPHA_THRESHOLD,
    EPS2D,
    MAX_ALPHA,
    TRANSMITTANCE_THRESHOLD,
    check_inputs,
    project,
    take_rows,
)
from trioman.toolkit.render.tiles import bin_gaussians

BACKENDS = ("auto", "torch", "native")  # see rasterize()
TILE_RANGE = (4, 16)  # the torch path's default tile side's bounds, pixels (docs/design.md, "How the renderers compute it")
NATIVE_TILE = 16  # the C kernel's default tile side: its cost follows the boxes, not the tile; fewer pairs to bin
DEFAULT_CHUNK_ELEMENTS = 1 << 18  # pixel x Gaussian entries per dense block tensor (1 MiB in float32)
KB_MIN = 16  # shortest block along the lists

_F32 = torch.float32
_THR_A32 = float(torch.tensor(ALPHA_THRESHOLD, dtype=_F32))  # 1/255 rounded to float32
_THR_A32_PREV = float(torch.nextafter(torch.tensor(_THR_A32), torch.tensor(0.0)))  # x > this <=> x >= 1/255f
_THR_T32 = float(torch.tensor(TRANSMITTANCE_THRESHOLD, dtype=_F32))  # 1e-4 rounded to float32
_SQRT_HALF = math.sqrt(0.5)
_FAR_U = 1e4  # added to u in columns outside a Gaussian's box: alpha 0, finite gradients
_FAR_HV = -1e4  # added to the log-opacity term in rows outside the box; the padding pair's value
_MIN_S = -60.0  # exp argument floor: exp(-60) is still a normal float32 (exp's underflow path is slow)

# columns of the per-Gaussian input of _Raster: mean2d x, y (0, 1), Cholesky a, b, c, log o, rgb (6:9), z (9)
_A, _B, _C, _LNO = 2, 3, 4, 5


class RenderOutput(NamedTuple):
    rgb: torch.Tensor  # [H, W, 3]
    alpha: torch.Tensor  # [H, W]
    depth: torch.Tensor  # [H, W] sum of w_i z_i (not normalised)


# --------------------------------------------------------------------------------------------
# the dense block kernel
#
# For a pair (tile, Gaussian), with s the tile side and L_l = l - (s - 1) / 2 the offset of pixel row
# or column l from the tile centre, the exponent of o exp(-sigma) is
#     log o - sigma = hv[row] - (colt[col] + rowt[row])^2,
#     colt[l] = u0 + a L_l      (+ FAR_U in columns outside the box)
#     rowt[l] = b L_l
#     hv[l]   = log o - (v0 + c L_l)^2      (+ FAR_HV in rows outside the box)
# where (a, b, c) is the Cholesky factor of the conic scaled by sqrt(1/2) and (u0, v0) = (a dx + b dy,
# c dy) at the tile centre (dx, dy = centre - mean2d). The terms of all pairs are the rows of one
# [P + 1, 3 s + 4] matrix (the pair's rgb and z in the last 4 columns; row P is a padding pair that is
# never visible), so a block needs one gather.


def _pair_terms(params, feats, box, s: int):
    """params [6, P] (u0, v0, a, b, c, log o), feats [4, P], box [4, P] -> terms [P + 1, 3 s + 4]."""
    u0, v0, a, b, c, lno = (x[:, None] for x in params)
    dt = params.dtype
    L = torch.arange(s, device=params.device, dtype=dt) - (s - 1) / 2  # [s]
    n = params.shape[1]
    terms = params.new_empty(n + 1, 3 * s + 4)
    colt, rowt, hv = terms[:n, :s], terms[:n, s:2 * s], terms[:n, 2 * s:3 * s]
    outside = torch.empty(n, s, dtype=_F32, device=params.device)
    L32 = L.to(_F32)
    torch.addcmul(u0, a, L, out=colt)
    torch.gt((box[0][:, None] + L32).abs_(), box[2][:, None], out=outside)  # column outside the box
    colt.add_(outside, alpha=_FAR_U)
    torch.mul(b, L, out=rowt)
    v = torch.addcmul(v0, c, L)
    torch.addcmul(lno, v, v, value=-1.0, out=hv)
    torch.gt((box[1][:, None] + L32).abs_(), box[3][:, None], out=outside)  # row outside the box
    hv.add_(outside, alpha=_FAR_HV)
    terms[:n, 3 * s:] = feats.T
    terms[n] = 0.0
    terms[n, :s] = _FAR_U
    terms[n, 2 * s:3 * s] = _FAR_HV
    return terms


class _Block(NamedTuple):
    tiles: torch.Tensor  # [Ta] active tiles (positions in the chunk)
    k0: int  # first list position of the block
    kb: int  # block length
    carry: torch.Tensor  # [Ta, s, s] T before the block (render dtype), 0 where a pixel has stopped
    carry32: torch.Tensor  # the same in float32 (the same tensor when rendering in float32)


def _gather_block(terms, tile_start, tile_count, t, k0: int, kb: int):
    """-> pidx [Ta, kb] (P for padding), X [Ta, 3 s + 4, kb]: colt, rowt, hv, then rgb and z."""
    n_pairs = terms.shape[0] - 1
    ta = t.numel()
    k = torch.arange(k0, k0 + kb, device=terms.device)
    pidx = tile_start[t][:, None] + k
    pidx = torch.where(k < tile_count[t][:, None], pidx, n_pairs)
    X = terms.index_select(0, pidx.view(-1)).view(ta, kb, -1).transpose(1, 2).contiguous()
    return pidx, X


def _block_alpha(X, s: int):
    """-> U [Ta, s, s, kb] (row, column, Gaussian) and alpha = min(0.99, o exp(-sigma)), 0 where skipped."""
    colt, rowt, hv = X[:, :s], X[:, s:2 * s], X[:, 2 * s:3 * s]
    U = colt[:, None, :, :] + rowt[:, :, None, :]
    G = torch.addcmul(hv[:, :, None, :], U, U, value=-1.0)
    G.clamp_(min=_MIN_S).exp_()  # o exp(-sigma)
    if G.dtype == _F32:
        F.threshold(G, _THR_A32_PREV, 0.0, inplace=True)  # skip alpha < 1/255
    else:  # the skip test on float32 values
        G.mul_(G.to(_F32) >= _THR_A32)
    return U, G.clamp_(max=MAX_ALPHA)


def _transmittance(alpha, blk: _Block):
    """-> onem [..., kb + 1] (T before the block, then 1 - alpha), P = cumprod(onem): T before each
    Gaussian, then after the last; incl (1.0 / 0.0): not stopped (T (1 - alpha) > 1e-4 on float32
    values; a prefix of the block); P32 (the float32 P when rendering in float64) or None."""
    shape = alpha.shape[:-1] + (alpha.shape[-1] + 1,)
    onem = alpha.new_empty(shape)
    onem[..., 0] = blk.carry
    torch.add(torch.ones((), dtype=alpha.dtype), alpha, alpha=-1.0, out=onem[..., 1:])
    P = torch.cumprod(onem, -1)
    incl = torch.empty_like(alpha)
    if alpha.dtype == _F32:
        return onem, P, torch.gt(P[..., 1:], _THR_T32, out=incl), None
    a32 = alpha.to(_F32)
    P32 = a32.new_empty(shape)
    P32[..., 0] = blk.carry32
    torch.add(torch.ones((), dtype=_F32), a32, alpha=-1.0, out=P32[..., 1:])
    P32 = torch.cumprod(P32, -1)
    return onem, P, torch.gt(P32[..., 1:], _THR_T32, out=incl), P32


def _plan_chunks(tile_count: torch.Tensor, chunk_elements: int, s: int) -> list[list[int]]:
    """Non-empty tiles by decreasing list length, in chunks of at most chunk_elements / (s^2 KB_MIN)."""
    count = tile_count.tolist()
    order = sorted((t for t, c in enumerate(count) if c > 0), key=lambda t: -count[t])
    per = max(1, chunk_elements // (s * s * KB_MIN))
    return [order[i:i + per] for i in range(0, len(order), per)]


def _pair_params(gq, pair_gauss, centre, radii, dt):
    """Per pair: params [6, P] (u0, v0, a, b, c, log o), feats [4, P], box [4, P] and the float64
    centre offsets (dx, dy) [2, P] (see the kernel comment)."""
    Q = gq[pair_gauss]  # [P, 10] float64
    d = centre - Q[:, :2].T  # [2, P]
    u0 = Q[:, _A] * d[0] + Q[:, _B] * d[1]
    v0 = Q[:, _C] * d[1]
    params = torch.stack([u0, v0, Q[:, _A], Q[:, _B], Q[:, _C], Q[:, _LNO]]).to(dt)
    feats = Q[:, 6:].T.to(dt)
    box = torch.cat([d, radii[pair_gauss].T]).to(_F32)
    return params, feats, box, d


class _Raster(torch.autograd.Function):
    """gq [M, 10] float64 per visible Gaussian: (mean2d x, y, a, b, c, log o, r, g, b, z), with (a, b, c)
    the conic's Cholesky factor scaled by sqrt(1/2). -> per tile color [T, 4, s^2] (sum w c, sum w z)
    and T_final [T, s^2], in ``dt``. Not differentiable: radii [M, 2], the bins, inside [T, s, s]."""

    @staticmethod
    def forward(ctx, gq, radii, pair_gauss, pair_tile, tile_start, tile_count, tiles_x, inside, s, chunk_elements, dt):
        dev = gq.device
        tile_xy = torch.stack([pair_tile % tiles_x, torch.div(pair_tile, tiles_x, rounding_mode="floor")])
        centre = (tile_xy * s).to(torch.float64) + s / 2  # [2, P] pixel coordinates of each pair's tile centre
        params, feats, box, d = _pair_params(gq, pair_gauss, centre, radii, dt)
        terms = _pair_terms(params, feats, box, s)
        n_tiles = tile_count.shape[0]
        color = params.new_zeros(n_tiles, 4, s * s)
        T_final = params.new_ones(n_tiles, s, s)
        plan = []
        for tiles_l in _plan_chunks(tile_count, chunk_elements, s):
            tiles = torch.tensor(tiles_l, dtype=torch.int64, device=dev)
            counts = tile_count[tiles]
            T = inside[tiles].to(dt)  # T after the last included Gaussian (1 outside the image: unused)
            T32 = T if dt == _F32 else T.to(_F32)
            alive = inside[tiles].to(dt)  # 1.0 until a pixel stops (0 outside the image)
            acc = params.new_zeros(len(tiles_l), 4, s * s)
            local = torch.arange(len(tiles_l), device=dev)
            blocks = []
            k0 = 0
            while local.numel():
                ta = local.numel()
                kb = min(max(KB_MIN, chunk_elements // (ta * s * s)), int(counts[local].max()) - k0)
                t = tiles[local]
                live = alive[local]
                carry = T[local] * live
                blk = _Block(local, k0, kb, carry, carry if dt == _F32 else T32[local] * live.to(_F32))
                blocks.append(blk)
                _, X = _gather_block(terms, tile_start, tile_count, t, k0, kb)
                _, alpha = _block_alpha(X, s)
                _, P, incl, P32 = _transmittance(alpha, blk)
                w = alpha.mul_(P[..., :-1]).mul_(incl).view(ta, s * s, kb)
                acc.index_add_(0, local, torch.bmm(X[:, 3 * s:], w.transpose(1, 2)))
                n = incl.sum(-1, keepdim=True).long()  # included Gaussians (a prefix of the block)
                T[local] = torch.where(live > 0, P.gather(-1, n)[..., 0], T[local])
                if dt != _F32:
                    T32[local] = torch.where(live > 0, P32.gather(-1, n)[..., 0], T32[local])
                alive[local] = live * (n[..., 0] == kb)
                k0 += kb
                local = local[(counts[local] > k0) & (alive[local].flatten(1).amax(1) > 0)]
            color[tiles] = acc
            T_final[tiles] = T
            plan.append((tiles, blocks))
        ctx.plan = plan
        ctx.s = s
        ctx.n_gauss = gq.shape[0]
        ctx.save_for_backward(params, d, pair_gauss, terms, tile_start, tile_count, T_final)
        return color, T_final.view(n_tiles, s * s)

    @staticmethod
    @once_differentiable
    def backward(ctx, g_color, g_T):
        with stage("rasterizer backward"):
            return _Raster._backward(ctx, g_color, g_T)

    @staticmethod
    def _backward(ctx, g_color, g_T):
        """The backward pass (class doc): per tile chunk, its blocks back to front."""
        params, d, pair_gauss, terms, tile_start, tile_count, T_final = ctx.saved_tensors
        s = ctx.s
        g_terms = torch.zeros_like(terms)  # [P + 1, 3 s + 4]
        g_color = g_color.contiguous()  # [T, 4, s^2]
        g_T = g_T.reshape(-1, s, s)
        for tiles, blocks in ctx.plan:
            # after a block: sum over later Gaussians of w e, plus T_final dL/dT_final (per pixel)
            suffix = (T_final[tiles] * g_T[tiles]).unsqueeze(-1)  # [Tc, s, s, 1]
            for blk in reversed(blocks):
                t = tiles[blk.tiles]
                ta, kb = t.numel(), blk.kb
                pidx, X = _gather_block(terms, tile_start, tile_count, t, blk.k0, kb)
                U, alpha = _block_alpha(X, s)
                onem, P, incl, _ = _transmittance(alpha, blk)
                Texcl = P[..., :-1]
                ai = alpha.mul_(incl)  # the alphas that count
                w = ai * Texcl
                # d alpha / d(log o - sigma) = alpha where it counts and is not capped (gsplat's backward)
                D = torch.lt(ai, MAX_ALPHA, out=torch.empty_like(ai)).mul_(ai)
                go = g_color[t]  # [ta, 4, s^2]
                e = torch.bmm(go.transpose(1, 2), X[:, 3 * s:]).view(ta, s, s, kb)  # d L / d w
                g_ft = torch.bmm(go, w.view(ta, s * s, kb))  # [ta, 4, kb]
                cs = torch.cumsum(w.mul_(e), -1)
                after = suffix[blk.tiles] + cs[..., -1:]
                suffix[blk.tiles] = after
                S = torch.sub(after, cs, out=cs)  # sum_{j > k} w_j e_j + T_final dL/dT_final
                g = e.mul_(Texcl).addcdiv_(S, onem[..., 1:], value=-1.0)  # d L / d alpha_k
                g.mul_(D)  # d L / d (log o - sigma)
                gU = U.mul_(g)
                gX = torch.cat([gU.sum(1).mul_(-2.0), gU.sum(2).mul_(-2.0), g.sum(2), g_ft], 1)  # [ta, R, kb]
                g_terms.index_copy_(0, pidx.view(-1), gX.transpose(1, 2).reshape(ta * kb, -1))
        # row / column terms -> per-pair scalars -> per-Gaussian inputs (float64)
        n = params.shape[1]
        u0, v0, a, b, c, lno = params
        L = (torch.arange(s, device=params.device, dtype=params.dtype) - (s - 1) / 2)[:, None]
        gT = g_terms[:n].T
        g_colt, g_rowt, g_hv = gT[:s], gT[s:2 * s], gT[2 * s:3 * s]
        g_v = torch.addcmul(v0, c, L).mul_(g_hv).mul_(-2.0)
        f64 = torch.float64
        g_u0, g_v0 = g_colt.sum(0).to(f64), g_v.sum(0).to(f64)
        a, b, c = a.to(f64), b.to(f64), c.to(f64)
        g_pair = torch.stack([
            -g_u0 * a,  # mean2d x (d = centre - mean2d)
            -g_u0 * b - g_v0 * c,  # mean2d y
            (g_colt * L).sum(0).to(f64) + g_u0 * d[0],  # a
            (g_rowt * L).sum(0).to(f64) + g_u0 * d[1],  # b
            (g_v * L).sum(0).to(f64) + g_v0 * d[1],  # c
            g_hv.sum(0).to(f64),  # log o
        ], 1)
        g_pair = torch.cat([g_pair, gT[3 * s:].T.to(f64)], 1)  # [P, 10]
        g_gq = g_pair.new_zeros(ctx.n_gauss, 10).index_add_(0, pair_gauss, g_pair)
        return (g_gq,) + (None,) * 10


def _ptr(x: torch.Tensor) -> int:
    assert x.is_contiguous()
    return x.data_ptr()


_POOLS: dict[tuple[int, int], ThreadPoolExecutor] = {}  # by (process id, threads): a forked child makes its own


def _tile_ranges(bins, n_tiles: int) -> list[tuple[int, int]]:
    """Contiguous tile ranges with about equal pair counts, two per torch thread (one range on one thread)."""
    n = min(torch.get_num_threads(), n_tiles)
    if n <= 1:
        return [(0, n_tiles)]
    ends = (bins.tile_start + bins.tile_count).tolist()  # pairs up to the end of each tile
    total, parts = ends[-1], 2 * n
    cuts = [0] + [bisect.bisect_left(ends, total * k / parts) + 1 for k in range(1, parts)] + [n_tiles]
    return [(a, b) for a, b in zip(cuts, cuts[1:]) if a < b]


def _over_tiles(fn, args: tuple, ranges: list[tuple[int, int]]) -> None:
    """fn(*args, t0, t1) for each tile range: on torch's thread count of Python threads (ctypes releases the
    GIL during the call), inline for one range. A non-zero return is an error."""
    if len(ranges) == 1:
        codes = [fn(*args, *ranges[0])]
    else:
        n = torch.get_num_threads()
        pool = _POOLS.get((os.getpid(), n))
        if pool is None:
            pool = _POOLS[(os.getpid(), n)] = ThreadPoolExecutor(n, thread_name_prefix="trioman-raster")
        codes = list(pool.map(lambda r: fn(*args, *r), ranges))
    if any(codes):
        raise RuntimeError(f"the C rasterizer kernel failed (codes {codes})")


class _NativeRaster(torch.autograd.Function):
    """``_Raster``'s forward and backward in C (raster_cpu.c), float32 on the CPU: gq [M, 10] float64,
    radii [M, 2] float64, the bins, the tile side s -> color [T, 4, s^2], T_final [T, s^2] (float32)."""

    @staticmethod
    def forward(ctx, gq, radii, bins, s, width, height, lib):
        n_tiles = bins.tiles_x * bins.tiles_y
        color = torch.empty(n_tiles, 4, s * s, dtype=_F32)
        T_final = torch.empty(n_tiles, s * s, dtype=_F32)
        last = torch.empty(n_tiles, s * s, dtype=torch.int32)  # list position where each pixel stopped
        scene = (gq.detach().contiguous(), radii.to(torch.float64).contiguous(), bins.pair_gauss.contiguous(),
                 bins.tile_start.contiguous(), bins.tile_count.contiguous())
        args = (*map(_ptr, scene), bins.tiles_x, s, width, height)
        ranges = _tile_ranges(bins, n_tiles)
        _over_tiles(lib.raster_forward, args, [r + (_ptr(color), _ptr(T_final), _ptr(last)) for r in ranges])
        ctx.scene, ctx.args, ctx.ranges, ctx.lib = scene, args, ranges, lib
        ctx.save_for_backward(T_final, last)
        return color, T_final

    @staticmethod
    @once_differentiable
    def backward(ctx, g_color, g_T):
        with stage("rasterizer backward"):
            T_final, last = ctx.saved_tensors
            gq, pair_gauss = ctx.scene[0], ctx.scene[2]
            g_color, g_T = g_color.to(_F32).contiguous(), g_T.to(_F32).contiguous()
            g_pair = torch.empty(pair_gauss.shape[0], 10, dtype=torch.float64)  # per pair, each written once
            out = tuple(map(_ptr, (T_final, last, g_color, g_T, g_pair)))
            _over_tiles(ctx.lib.raster_backward, ctx.args, [r + out for r in ctx.ranges])
            g_gq = torch.zeros_like(gq)
            ctx.lib.raster_sum_pairs(_ptr(pair_gauss), pair_gauss.shape[0], _ptr(g_pair), _ptr(g_gq))
        return (g_gq,) + (None,) * 6


def _native_kernel(backend: str, dt: torch.dtype, device: torch.device) -> ctypes.CDLL | None:
    """The C kernel's library when ``backend`` selects it for this render, else None (the torch path)."""
    if backend == "torch":
        return None
    fits = dt == _F32 and device.type == "cpu"
    if backend == "auto":
        return native.load() if fits else None
    if not fits:
        raise ValueError(f"backend: 'native' renders float32 on the CPU, got {dt} on {device}")
    lib = native.load()
    if lib is None:
        raise RuntimeError(f"backend='native': the C rasterizer kernel is unavailable ({native.ENV_SWITCH}=0, "
                           "or it could not be built: see the warning)")
    return lib


def tile_side(radii: torch.Tensor) -> int:
    """radii [M, 2] of the visible Gaussians (whole pixels) -> the default tile side: twice the median of
    the larger radius, within ``TILE_RANGE``."""
    median = float(radii.detach().amax(1).median())
    return int(min(max(2 * median, TILE_RANGE[0]), TILE_RANGE[1]))


# --------------------------------------------------------------------------------------------
# public entry point


def rasterize(
    means: torch.Tensor,  # [N, 3]
    quats: torch.Tensor,  # [N, 4] wxyz, normalised inside (zero = identity)
    scales: torch.Tensor,  # [N, 3] activated, metres
    opacities: torch.Tensor,  # [N] in [0, 1]
    colors: torch.Tensor,  # [N, 3]
    viewmat: torch.Tensor,  # [4, 4] world -> camera (OpenCV)
    K: torch.Tensor,  # [3, 3]
    width: int,
    height: int,
    background: torch.Tensor | None = None,  # [3]; None: black
    near_plane: float = 0.01,
    far_plane: float = 1e10,
    *,
    chunk_elements: int = DEFAULT_CHUNK_ELEMENTS,
    tile_size: int | None = None,
    backend: str = "auto",
) -> RenderOutput:
    """Render Gaussians -> RenderOutput(rgb [H, W, 3], alpha [H, W], depth [H, W]) (docs/design.md, "Renderer semantics").

    Differentiable w.r.t. means, quats, scales, opacities, colors and background. ``depth`` is the
    alpha-weighted sum of camera depths, not normalised. Outputs are float32 (float64 for float64
    ``means``). N == 0 or nothing visible gives the background. On CUDA tensors with gsplat installed
    the work goes to ``gsplat.rasterization`` (see :func:`_rasterize_gsplat`). ``chunk_elements``
    bounds the dense pixel x Gaussian block tensors (peak memory); ``tile_size`` is the tile side (None:
    ``NATIVE_TILE`` for the C kernel, :func:`tile_side` of the visible Gaussians for the torch path).
    Neither changes the result beyond float32 rounding of the colour sums. ``backend``: "torch" (the
    reference ``_Raster``), "native" (the C kernel; float32 CPU renders only, an error when it cannot be
    loaded) or "auto" (the C kernel for float32 CPU renders when it loads, else torch); the two agree
    up to float32 rounding.
    """
    n, width, height = check_inputs(means, quats, scales, opacities, colors, viewmat, K, width, height,
                                    background, near_plane, far_plane)
    if isinstance(chunk_elements, bool) or not isinstance(chunk_elements, int) or chunk_elements < 1:
        raise ValueError(f"chunk_elements: must be an int >= 1, got {chunk_elements!r}")
    if tile_size is not None and (isinstance(tile_size, bool) or not isinstance(tile_size, int)
                                  or not 1 <= tile_size <= 64):
        raise ValueError(f"tile_size: must be an int in [1, 64], got {tile_size!r}")
    if backend not in BACKENDS:
        raise ValueError(f"backend: must be one of {BACKENDS}, got {backend!r}")
    dt = torch.float64 if means.dtype == torch.float64 else _F32
    dev = means.device
    bg = background.to(dt) if background is not None else torch.zeros(3, dtype=dt, device=dev)

    def nothing_visible():  # the background, with the inputs still in the graph (zero gradients)
        link = sum(x.sum() for x in (means, quats, scales, opacities, colors)).to(dt) * 0
        zeros = torch.zeros(height, width, dtype=dt, device=dev) + link
        return RenderOutput(bg.expand(height, width, 3) + link, zeros, zeros.clone())

    if n == 0:
        return nothing_visible()
    if means.is_cuda and _gsplat_available():
        return _rasterize_gsplat(means, quats, scales, opacities, colors, viewmat, K, width, height, background,
                                 near_plane, far_plane)
    lib = _native_kernel(backend, dt, dev)
    with stage("projection"):
        p = project(means, quats, scales, opacities, viewmat, K, width, height, near_plane, far_plane)
        if p.ids.numel() == 0:
            return nothing_visible()
        f64 = torch.float64
        gq = torch.cat([p.means2d, p.chol * _SQRT_HALF, torch.log(take_rows(opacities, p.ids).to(f64))[:, None],
                        take_rows(colors, p.ids).to(f64), p.depths[:, None]], 1)  # [M, 10]
    with stage("tile binning"):
        s = tile_size if tile_size is not None else NATIVE_TILE if lib is not None else tile_side(p.radii)
        bins = bin_gaussians(p.means2d, p.radii, p.depths, width, height, s)
    with stage("rasterizer forward"):
        if lib is not None:
            color, T_final = _NativeRaster.apply(gq, p.radii, bins, s, width, height, lib)
        else:
            color, T_final = _torch_raster(gq, p.radii, bins, s, width, height, chunk_elements, dt)

    def to_image(x):  # [T, C, s^2] -> [H, W, C]
        C = x.shape[1]
        img = x.view(bins.tiles_y, bins.tiles_x, C, s, s).permute(0, 3, 1, 4, 2)
        return img.reshape(bins.tiles_y * s, bins.tiles_x * s, C)[:height, :width]

    color = to_image(color)
    T = to_image(T_final.unsqueeze(1))
    rgb = color[..., :3] + T * bg
    return RenderOutput(rgb, 1.0 - T[..., 0], color[..., 3])


def _torch_raster(gq, radii, bins, s: int, width: int, height: int, chunk_elements: int, dt):
    """``_Raster`` on the bins: color [T, 4, s^2], T_final [T, s^2] in ``dt``."""
    dev = gq.device
    ty, tx = torch.meshgrid(torch.arange(bins.tiles_y, device=dev), torch.arange(bins.tiles_x, device=dev),
                            indexing="ij")
    li = torch.arange(s, device=dev)
    inside = (ty.reshape(-1, 1, 1) * s + li[:, None] < height) & (tx.reshape(-1, 1, 1) * s + li[None, :] < width)
    return _Raster.apply(gq, radii, bins.pair_gauss, bins.pair_tile, bins.tile_start, bins.tile_count,
                         bins.tiles_x, inside, s, chunk_elements, dt)


# --------------------------------------------------------------------------------------------
# CUDA: gsplat


def _gsplat_available() -> bool:
    if not torch.cuda.is_available():
        return False
    try:
        import gsplat  # noqa: F401
    except Exception:
        return False
    return True


def _rasterize_gsplat(means, quats, scales, opacities, colors, viewmat, K, width, height, background,
                      near_plane, far_plane) -> RenderOutput:
    """gsplat.rasterization: classic mode, eps2d 0.3, unpacked, render_mode "RGB+D" (D = sum w z).

    Known differences from the CPU path: gsplat <= 1.5.3 caps alpha at 0.999 (not 0.99) and projects
    in float32; its CUDA quaternion normalisation gives NaN for a zero quaternion, so zero quaternions
    are replaced by the identity here.
    """
    import gsplat

    f = torch.float32
    identity = torch.tensor([1.0, 0.0, 0.0, 0.0], dtype=f, device=means.device)
    quats = torch.where((quats == 0).all(-1, keepdim=True), identity, quats.to(f))
    bg = None if background is None else background.to(f)[None]  # gsplat appends the depth channel's 0
    out, alphas, _ = gsplat.rasterization(
        means.to(f), quats, scales.to(f), opacities.to(f), colors.to(f), viewmat.to(f)[None], K.to(f)[None],
        width, height, near_plane=near_plane, far_plane=far_plane, eps2d=EPS2D, packed=False,
        rasterize_mode="classic", render_mode="RGB+D", backgrounds=bg,
    )
    return RenderOutput(out[0, ..., :3], alphas[0, ..., 0], out[0, ..., 3])
