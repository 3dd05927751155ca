"""Rasterizer timings for ``trioman bench train``: the tile-binned rasterizer against a dense torch
implementation (every visible Gaussian at every pixel) and the float64 brute-force test oracle,
measured side by side on the default avatar in one run."""

from __future__ import annotations

import importlib.util
import time
from pathlib import Path

import numpy as np
import torch
from torch.utils.checkpoint import checkpoint

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
        alpha = torch.clamp(op * torch.exp(-sigma), max=0.99)
        alpha = torch.where((sigma >= 0) & (alpha >= 1 / 255), alpha, torch.zeros_like(alpha))
        T_incl = torch.cumprod(1 - alpha, dim=1)
        T_excl = torch.cat([torch.ones_like(T_incl[:, :1]), T_incl[:, :-1]], 1)
        w = alpha * T_excl * (T_incl > 1e-4)
        T_end = 1 - w.sum(1, keepdim=True)  # transmittance left after the kept Gaussians
        return w @ col + T_end * background

    out = [checkpoint(chunk, pix[s : s + pixels_per_chunk], m2, con, op, col, use_reentrant=False)
           for s in range(0, len(pix), pixels_per_chunk)]
    return torch.cat(out).reshape(height, width, 3)


def _oracle():
    """The brute-force reference from the test suite (present in a source checkout)."""
    path = Path(__file__).resolve().parents[1] / "tests" / "toolkit" / "render" / "reference.py"
    if not path.is_file():
        return None
    spec = importlib.util.spec_from_file_location("trioman_raster_reference", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.rasterize_reference


def _time(fn, repeats: int) -> float:
    fn()  # warm-up
    t = time.perf_counter()
    for _ in range(repeats):
        fn()
    return (time.perf_counter() - t) / repeats


@flush_denormals()
def bench_rasterizer(gaussians, viewmat: torch.Tensor, K: torch.Tensor, sizes=(128, 256), repeats: int = 5,
                     oracle_max_pixels: int = 128 * 128) -> list[dict]:
    """Seconds per forward and forward+backward for each image size and implementation."""
    oracle = _oracle()
    rows = []
    for size in sizes:
        k = K.clone()
        k[:2] *= size / (2 * float(K[0, 2]))  # K is for a square image of side 2 cx
        leaves = [t.detach().clone().requires_grad_(True) for t in gaussians]
        bg = torch.ones(3)

        def fwd(fn):
            with torch.no_grad():
                fn(*leaves, viewmat, k, size, size, bg)

        def fwd_bwd(fn):
            out = fn(*leaves, viewmat, k, size, size, bg)
            (out.rgb if hasattr(out, "rgb") else out).sum().backward()

        tiled = lambda *a: rasterize(*a[:-1], background=a[-1])  # noqa: E731
        row = {"size": size, "gaussians": int(leaves[0].shape[0]),
               "tiled_fwd_s": _time(lambda: fwd(tiled), repeats),
               "tiled_fwd_bwd_s": _time(lambda: fwd_bwd(tiled), repeats),
               "dense_fwd_s": _time(lambda: fwd(dense_rasterize), max(1, repeats // 2)),
               "dense_fwd_bwd_s": _time(lambda: fwd_bwd(dense_rasterize), max(1, repeats // 2))}
        if oracle is not None and size * size <= oracle_max_pixels:
            arrays = [t.detach().double().numpy() for t in leaves]
            row["oracle_fwd_s"] = _time(lambda: oracle(*arrays, viewmat.double().numpy(), k.double().numpy(), size, size,
                                                       np.ones(3)), 1)
        rows.append(row)
    return rows
