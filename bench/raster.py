"""Rasterizer timings for ``trioman bench train``: the tile-binned rasterizer against a dense torch
implementation (every visible Gaussian at every pixel) and the float64 brute-force oracle
(:mod:`trioman.runtime.render.reference`), measured side by side on the default avatar in one run."""

from __future__ import annotations

from functools import partial

import numpy as np
import torch
from torch.utils.checkpoint import checkpoint

from trioman.bench.common import mean_time
from trioman.runtime.render.projection import ALPHA_THRESHOLD, MAX_ALPHA, TRANSMITTANCE_THRESHOLD
from trioman.runtime.render.reference import rasterize_reference
from trioman.toolkit.cpu import flush_denormals
from trioman.toolkit.render import rasterize
from trioman.toolkit.render.projection import project_gaussians


def dense_rasterize(means, quats, scales, opacities, colors, viewmat, K, width, height, background,
                    pixels_per_chunk: int = 2048) -> torch.Tensor:
    """All visible Gaussians x all pixels, sorted by depth, composited with cumprod; chunked over pixels
    with activation checkpointing so memory stays bounded. Same alpha rules, no tile or box test. -> [H, W, 3]."""
    p = project_gaussians(means, quats, scales, opacities, viewmat, K, width, height)
    ids = torch.nonzero(p.visible)[:, 0]
    ids = ids[torch.argsort(p.depths[ids].detach(), stable=True)]
    m2, con, op, col = p.means2d[ids].float(), p.conics[ids].float(), opacities[ids], colors[ids]
    jj, ii = torch.meshgrid(torch.arange(width), torch.arange(height), indexing="xy")
    pix = torch.stack([jj.reshape(-1) + 0.5, ii.reshape(-1) + 0.5], 1).float()

    def chunk(px: torch.Tensor, m2, con, op, col) -> torch.Tensor:
        d = px[:, None, :] - m2[None]  # [P, M, 2]
        sigma = 0.5 * (con[:, 0] * d[..., 0] ** 2 + con[:, 2] * d[..., 1] ** 2) + con[:, 1] * d[..., 0] * d[..., 1]
        alpha = torch.clamp(op * torch.exp(-sigma), max=MAX_ALPHA)
        alpha = torch.where((sigma >= 0) & (alpha >= ALPHA_THRESHOLD), alpha, torch.zeros_like(alpha))
        T_incl = torch.cumprod(1 - alpha, dim=1)
        T_excl = torch.cat([torch.ones_like(T_incl[:, :1]), T_incl[:, :-1]], 1)
        w = alpha * T_excl * (T_incl > TRANSMITTANCE_THRESHOLD)
        T_end = 1 - w.sum(1, keepdim=True)  # transmittance left after the kept Gaussians
        return w @ col + T_end * background

    out = [checkpoint(chunk, pix[s : s + pixels_per_chunk], m2, con, op, col, use_reentrant=False)
           for s in range(0, len(pix), pixels_per_chunk)]
    return torch.cat(out).reshape(height, width, 3)


@flush_denormals()
def bench_rasterizer(gaussians, viewmat: torch.Tensor, K: torch.Tensor, sizes=(128, 256), repeats: int = 5,
                     oracle_max_pixels: int = 128 * 128) -> list[dict]:
    """Seconds per forward and forward+backward for each image size and implementation."""
    def tiled(*a):
        return rasterize(*a[:-1], background=a[-1])

    def fwd(fn, args):
        with torch.no_grad():
            fn(*args)

    def fwd_bwd(fn, args):
        out = fn(*args)
        (out.rgb if hasattr(out, "rgb") else out).sum().backward()

    rows = []
    for size in sizes:
        k = K.clone()
        k[:2] *= size / (2 * float(K[0, 2]))  # K is for a square image of side 2 cx
        leaves = [t.detach().clone().requires_grad_(True) for t in gaussians]
        args = (*leaves, viewmat, k, size, size, torch.ones(3))
        slow = max(1, repeats // 2)
        row = {"size": size, "gaussians": int(leaves[0].shape[0]),
               "tiled_fwd_s": mean_time(partial(fwd, tiled, args), repeats),
               "tiled_fwd_bwd_s": mean_time(partial(fwd_bwd, tiled, args), repeats),
               "dense_fwd_s": mean_time(partial(fwd, dense_rasterize, args), slow),
               "dense_fwd_bwd_s": mean_time(partial(fwd_bwd, dense_rasterize, args), slow)}
        if size * size <= oracle_max_pixels:
            arrays = [t.detach().double().numpy() for t in (*leaves, viewmat, k)]
            row["oracle_fwd_s"] = mean_time(partial(rasterize_reference, *arrays, size, size, np.ones(3)), 1)
        rows.append(row)
    return rows
