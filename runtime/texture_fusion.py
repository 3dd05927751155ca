"""A texture fused from every source frame: the body's UV texture that best explains the frames' pixels
through the image formation (bilinear texels, ``SUPERSAMPLE``^2 samples per pixel), by least squares with a
smoothness term, solved by preconditioned conjugate gradients (numpy only). Rendered at a Generator draw it is
the aligned reference's colour where the fused texels were seen (docs/augmentation.md, "The aligned
reference" and "A fused texture"): many frames' pixels of one surface point, each a different sampling of it, recover detail no single
frame holds, which carrying one frame's pixels through the mesh resamples away.
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import numpy as np

from trioman.runtime.mesh_raster import interpolate, rasterize_mesh
from trioman.runtime.skeleton import SkinnedMesh

__all__ = ["SUPERSAMPLE", "FusedTexture", "fuse_texture", "texel_rows"]

SUPERSAMPLE = 2  # samples per pixel side, box-filtered: the pixel's footprint on the texture


class FusedTexture(NamedTuple):
    texture: np.ndarray  # [R, R, 3] float32 colour
    seen: np.ndarray  # [R, R] float32: the texel's total weight in the frames' pixels (0: never seen)

    def render(self, mesh: SkinnedMesh, pose: np.ndarray, trans: np.ndarray, viewmat: np.ndarray, K: np.ndarray,
               width: int, height: int, min_seen: float) -> tuple[np.ndarray, np.ndarray]:
        """The texture on the posed body -> (rgb [H, W, 3] float32, 0 off the body; valid [H, W] bool: the pixel
        is covered by the body and every texel it samples has weight >= ``min_seen``)."""
        pix, idx, w = texel_rows(mesh, pose, trans, viewmat, K, width, height, self.texture.shape[0])
        rgb = np.zeros((height * width, 3), np.float32)
        valid = np.zeros(height * width, bool)
        rgb[pix] = np.einsum("mk,mkc->mc", w, self.texture.reshape(-1, 3)[idx])
        valid[pix] = self.seen.reshape(-1)[idx].min(axis=1) >= min_seen
        return np.clip(rgb, 0.0, 1.0).reshape(height, width, 3), valid.reshape(height, width)


def texel_rows(mesh: SkinnedMesh, pose: np.ndarray, trans: np.ndarray, viewmat: np.ndarray, K: np.ndarray,
               width: int, height: int, size: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The pixels the posed body covers whole (every sample) as rows of the image formation over a ``size``^2
    texture -> (pixel [M] flat index, texel [M, S] flat indices, weight [M, S]; S = 4 SUPERSAMPLE^2, each row's
    weights sum to 1). UVs as ``mesh_raster.sample_texture`` reads them (v up, texel centres at +0.5, clamped)."""
    if mesh.uvs is None or mesh.uv_faces is None:
        raise ValueError("mesh: has no UV coordinates; a fused texture needs the body model's UV layout")
    ss = SUPERSAMPLE
    Ks = np.array(K, np.float64)
    Ks[:2] *= ss
    verts = mesh.pose(np.asarray(pose, np.float64), np.asarray(trans, np.float64))
    frags = rasterize_mesh(verts, np.asarray(mesh.faces), np.asarray(viewmat, np.float64), Ks, width * ss, height * ss)
    whole = (frags.face_id >= 0).reshape(height, ss, width, ss).all(axis=(1, 3))
    uv = interpolate(frags, np.asarray(mesh.uvs), np.asarray(mesh.uv_faces)).reshape(height, ss, width, ss, 2)
    uv = uv.transpose(0, 2, 1, 3, 4).reshape(height, width, ss * ss, 2)[whole].astype(np.float64)  # [M, ss^2, 2]
    c, r = uv[..., 0] * size - 0.5, (1.0 - uv[..., 1]) * size - 0.5
    c0, r0 = np.floor(c), np.floor(r)
    fc, fr = c - c0, r - r0
    idx, wts = [], []
    for dr, dc, w in ((0, 0, (1 - fr) * (1 - fc)), (0, 1, (1 - fr) * fc), (1, 0, fr * (1 - fc)), (1, 1, fr * fc)):
        rr = np.clip(r0 + dr, 0, size - 1).astype(np.int64)
        cc = np.clip(c0 + dc, 0, size - 1).astype(np.int64)
        idx.append(rr * size + cc)
        wts.append(w / (ss * ss))
    m = len(uv)
    return (np.flatnonzero(whole.reshape(-1)), np.stack(idx, -1).reshape(m, -1),
            np.stack(wts, -1).reshape(m, -1).astype(np.float32))


def _laplacian(x: np.ndarray) -> np.ndarray:
    """x [R, R, C] -> [R, R, C]: the texel grid's graph Laplacian (each texel minus its 4-neighbours, summed)."""
    out = np.zeros_like(x)
    for axis in (0, 1):
        d = np.diff(x, axis=axis)
        lo = [slice(None)] * 3
        hi = [slice(None)] * 3
        lo[axis], hi[axis] = slice(None, -1), slice(1, None)
        out[tuple(lo)] -= d
        out[tuple(hi)] += d
    return out


def fuse_texture(mesh: SkinnedMesh, frames: int, frame: Callable[[int], tuple], size: int = 256, smooth: float = 0.02,
                 iterations: int = 200, min_mask: float = 0.99, tol: float = 1e-6) -> FusedTexture:
    """The texture minimising sum_pixels |formation(texture) - pixel|^2 + smooth |grad texture|^2 over the
    ``frames`` source frames; ``frame(p)`` -> (pose [J, 3], trans [3], viewmat [4, 4], K [3, 3], image [H, W, 3]
    colour, mask [H, W]); pixels with mask below ``min_mask`` (the silhouette's edge, the background) are left
    out. Texels no pixel sampled take their neighbours' colour from the smoothness term and have ``seen`` 0. The
    solve stops after ``iterations`` or when the residual is ``tol`` of the right-hand side; the texture is clipped
    to the frames' colour range."""
    if isinstance(size, bool) or not isinstance(size, int) or size < 2:
        raise ValueError(f"size: the texture's side in texels, an integer >= 2, got {size!r}")
    if not (np.isfinite(smooth) and smooth > 0):
        raise ValueError(f"smooth: must be a finite number > 0, got {smooth!r}")
    idx_all, w_all, b_all = [], [], []
    for p in range(frames):
        pose, trans, viewmat, K, image, mask = frame(p)
        H, W = np.asarray(mask).shape
        pix, idx, w = texel_rows(mesh, pose, trans, viewmat, K, W, H, size)
        keep = np.asarray(mask, np.float32).reshape(-1)[pix] >= min_mask
        idx_all.append(idx[keep])
        w_all.append(w[keep])
        b_all.append(np.asarray(image, np.float32).reshape(-1, 3)[pix[keep]])
    if not sum(len(i) for i in idx_all):
        raise ValueError(f"frames: none of the {frames} source frames shows a pixel wholly on the body inside its mask; "
                         "nothing to fuse a texture from")
    idx, w, b = np.concatenate(idx_all), np.concatenate(w_all).astype(np.float64), np.concatenate(b_all).astype(np.float64)
    n = size * size
    flat = idx.reshape(-1)

    def At(y: np.ndarray) -> np.ndarray:  # [M, 3] -> [n, 3]
        wy = (w[..., None] * y[:, None, :]).reshape(-1, 3)
        return np.stack([np.bincount(flat, wy[:, ch], minlength=n) for ch in range(3)], -1)

    def normal(x: np.ndarray) -> np.ndarray:  # (A^T A + smooth L) x, x [n, 3]
        ax = np.einsum("mk,mkc->mc", w, x[idx])
        return At(ax) + smooth * _laplacian(x.reshape(size, size, 3)).reshape(n, 3)

    seen = np.bincount(flat, w.reshape(-1), minlength=n)
    degree = np.full((size, size), 4.0)  # the Laplacian's diagonal: each texel's neighbour count
    degree[[0, -1], :] -= 1
    degree[:, [0, -1]] -= 1
    diag = np.bincount(flat, (w * w).reshape(-1), minlength=n) + smooth * degree.reshape(-1)
    rhs = At(b)
    # preconditioned conjugate gradients from the seen texels' mean colours, the three channels at once
    x = np.where(seen[:, None] > 0, rhs / np.maximum(seen, 1e-12)[:, None], b.mean(0)[None])
    r = rhs - normal(x)
    z = r / diag[:, None]
    d = z.copy()
    rz = (r * z).sum(0)
    for _ in range(iterations):
        q = normal(d)
        alpha = rz / np.maximum((d * q).sum(0), 1e-30)
        x += alpha * d
        r -= alpha * q
        z = r / diag[:, None]
        rz_new = (r * z).sum(0)
        if float(np.sqrt((r * r).sum())) <= tol * max(float(np.sqrt((rhs * rhs).sum())), 1e-30):
            break
        d = z + (rz_new / np.maximum(rz, 1e-30)) * d
        rz = rz_new
    # no colour outside the frames' range: an iterate stopped early can overshoot far where the smoothness term is
    # all that holds a texel (unseen texels under a small ``smooth``)
    x = np.clip(x, b.min(), b.max())
    return FusedTexture(x.reshape(size, size, 3).astype(np.float32), seen.reshape(size, size).astype(np.float32))
