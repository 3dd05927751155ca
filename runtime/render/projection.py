"""Input checks and the EWA projection of 3D Gaussians to the image (numpy; the twin of
``trioman.toolkit.render.projection``): docs/design.md, "Renderer semantics" and its "How the renderers
compute it" (factored covariance, Cholesky conic, cheap culling first).
"""

from __future__ import annotations

import math
import numbers
from typing import NamedTuple

import numpy as np

from trioman.runtime.rotations import quat_to_matrix

ALPHA_THRESHOLD = 1.0 / 255.0  # skip alpha below this; cull opacity below this
MAX_ALPHA = 0.99  # per-pixel alpha cap
TRANSMITTANCE_THRESHOLD = 1e-4  # stop when T (1 - alpha) <= this, that Gaussian excluded
EPS2D = 0.3  # px^2 added to the 2D covariance diagonal
MAX_EXTENT = 3.33  # sigmas; never active for opacity <= 1 (sqrt(2 ln 255) = 3.3290 < 3.33)

_F32 = np.float32


class Projected(NamedTuple):
    """Float64 screen-space values of the M Gaussians that reach the image, in input order; per-Gaussian
    vectors are rows over the Gaussians (each row contiguous)."""

    ids: np.ndarray  # [M] int64 indices into the N inputs
    means2d: np.ndarray  # [2, M] pixels (x, y)
    chol: np.ndarray  # [3, M] (a, b, c): sigma = 0.5 ((a dx + b dy)^2 + (c dy)^2)
    depths: np.ndarray  # [M] camera z of the centre
    radii: np.ndarray  # [2, M] whole numbers: the box |dx| <= r_x, |dy| <= r_y


# --------------------------------------------------------------------------------------------
# input checks


def check_size(name: str, value) -> int:
    """An image side: a positive int (bool refused). -> int; ValueError naming ``name``."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise ValueError(f"{name}: must be a positive int, got {value!r}")
    if value <= 0:
        raise ValueError(f"{name}: must be a positive int, got {value}")
    return int(value)


def check_shape(name: str, got: tuple, shape: tuple) -> None:
    """``got`` against ``shape`` (ints, or None for 'any'); ValueError naming ``name`` and both shapes."""
    want = "[" + ", ".join("N" if s is None else str(s) for s in shape) + "]"
    if len(got) != len(shape) or any(s is not None and s != d for s, d in zip(shape, got)):
        raise ValueError(f"{name}: expected shape {want}, got {list(got)}")


def check_values(scales: np.ndarray, opacities: np.ndarray | None, K: np.ndarray, near_plane: float,
                 far_plane: float) -> None:
    """The value rules both renderers share: scales [N, 3] >= 0, opacities [N] in [0, 1] (None: not
    given), K [3, 3] with fx, fy > 0, 0 < near_plane < far_plane (far may be inf). ValueError naming
    the argument and the count."""
    neg = int(np.count_nonzero(scales < 0))
    if neg:
        raise ValueError(f"scales: {neg} of {scales.size} values are negative (activated scales are >= 0)")
    if opacities is not None:
        out = int(np.count_nonzero((opacities < 0) | (opacities > 1)))
        if out:
            raise ValueError(f"opacities: {out} of {opacities.size} values lie outside [0, 1]")
    if not (K[0, 0] > 0 and K[1, 1] > 0):
        raise ValueError(f"K: focal lengths must be > 0, got fx={float(K[0, 0])}, fy={float(K[1, 1])}")
    near, far = float(near_plane), float(far_plane)
    if not (math.isfinite(near) and near > 0):
        raise ValueError(f"near_plane: must be a finite number > 0, got {near_plane}")
    if not (far > near):  # far may be inf
        raise ValueError(f"far_plane: must be > near_plane ({near}), got {far_plane}")


def _check_array(name: str, x, shape: tuple) -> np.ndarray:
    """shape: ints, or None for 'any'. -> the array (not copied); ValueError naming ``name``."""
    a = np.asarray(x)
    if a.dtype.kind not in "fiu":
        raise ValueError(f"{name}: expected a real-valued array, got dtype {a.dtype}")
    check_shape(name, a.shape, shape)
    if a.dtype.kind == "f":
        bad = a.size - int(np.count_nonzero(np.isfinite(a)))
        if bad:
            raise ValueError(f"{name}: {bad} of {a.size} values are NaN or Inf")
    return a


def check_inputs(means, quats, scales, opacities, colors, viewmat, K, width, height, background=None,
                 near_plane: float = 0.01, far_plane: float = 1e10) -> tuple[list[np.ndarray], int, int]:
    """Validate the renderer's inputs (ValueError naming the argument and the count).

    -> ([means, quats, scales, opacities, colors, viewmat, K, background or None] as arrays, W, H).
    """
    width = check_size("width", width)
    height = check_size("height", height)
    means = _check_array("means", means, (None, 3))
    n = means.shape[0]
    arrays = [means, _check_array("quats", quats, (n, 4)), _check_array("scales", scales, (n, 3)),
              _check_array("opacities", opacities, (n,)), _check_array("colors", colors, (n, 3)),
              _check_array("viewmat", viewmat, (4, 4)), _check_array("K", K, (3, 3)),
              None if background is None else _check_array("background", background, (3,))]
    check_values(arrays[2], arrays[3], arrays[6], near_plane, far_plane)
    return arrays, width, height


# --------------------------------------------------------------------------------------------
# projection


def _take(x: np.ndarray, ids: np.ndarray | None) -> np.ndarray:
    """x[ids] along the first axis (None: all of x), float64."""
    return np.asarray(x if ids is None else np.take(x, ids, axis=0), dtype=np.float64)


EXTENT_RULES = ("opacity", "3sigma")  # see project()


def _extent(opacities: np.ndarray, rule: str = "opacity") -> np.ndarray:
    """Sigmas of the radius box [M] -> [M]. "opacity": min(3.33, sqrt(2 ln(255 o))) (0 below o = 1/255),
    where alpha >= 1/255 can reach; "3sigma": 3 for every Gaussian (gsplat's radius rule)."""
    if rule == "3sigma":
        return np.full(len(opacities), 3.0)
    with np.errstate(divide="ignore"):
        return np.minimum(np.sqrt(np.maximum(2.0 * np.log(opacities * 255.0), 0.0)), MAX_EXTENT)


def _prefilter(means, scales, opacities, Rv, tv, Kd, width: int, height: int, near: float, far: float) -> np.ndarray:
    """Indices [M] of the Gaussians that may reach the image: centre depth within [near, far] and the
    3.33-sigma box of the largest scale on screen, in float32 with a relative margin of 1e-3 (float32
    rounding is ~1e-7) and 2 pixels, so the exact tests that follow decide every Gaussian it keeps.
    Skipped (every index kept) for a skewed K or coordinates beyond float32's comfortable range."""
    n = len(means)
    if Kd[0, 1] != 0 or Kd[1, 0] != 0 or n == 0 or not (np.max(means) < 1e30 and np.min(means) > -1e30):
        return np.arange(n)
    m = np.asarray(means, dtype=_F32)
    x, y, z = Rv.astype(_F32) @ m.T + tv.astype(_F32)[:, None]  # contiguous rows [N] each
    scale = np.maximum(np.maximum(np.abs(x), np.abs(y)), np.abs(z))  # error bound of each coordinate
    scale *= _F32(1e-3)
    scale += _F32(1e-6)
    keep = (z + scale >= near) & (z - scale <= far) & (np.asarray(opacities, dtype=_F32) >= _F32(ALPHA_THRESHOLD))
    ids = np.flatnonzero(keep)
    sc = np.asarray(scales, dtype=_F32)
    if len(ids) < n:  # nothing gathered when nothing is culled
        x, y, z, scale = (np.take(v, ids) for v in (x, y, z, scale))
        sc = np.take(sc, ids, axis=0)
    smax = np.maximum(np.maximum(sc[:, 0], sc[:, 1]), sc[:, 2])
    z0 = np.maximum(z - scale, _F32(near) * _F32(0.5))  # the smallest depth the centre may have
    z1 = z0 + 2 * scale  # the largest
    fx, fy, cx, cy = (_F32(v) for v in (Kd[0, 0], Kd[1, 1], Kd[0, 2], Kd[1, 2]))
    lim = _F32(max(width / fx, height / fy) * 2 + 1)  # >= the Jacobian's clamp |x'/z| of every axis
    g = smax * _F32(np.linalg.norm(Rv, 2) * 1.001 * max(fx, fy)) / z0
    r = _F32(MAX_EXTENT * 1.001) * np.sqrt(g * g * (1 + lim * lim) + _F32(EPS2D)) + _F32(2)
    # the centre's pixel over x in [x - scale, x + scale], z in [z0, z1]: x / z is extreme at a corner
    u_lo = cx + fx * np.minimum((x - scale) / z0, (x - scale) / z1)
    u_hi = cx + fx * np.maximum((x + scale) / z0, (x + scale) / z1)
    v_lo = cy + fy * np.minimum((y - scale) / z0, (y - scale) / z1)
    v_hi = cy + fy * np.maximum((y + scale) / z0, (y + scale) / z1)
    on = (u_hi + r > 0) & (u_lo - r < width) & (v_hi + r > 0) & (v_lo - r < height)
    return ids[on]


def project(
    means: np.ndarray,  # [N, 3]
    quats: np.ndarray,  # [N, 4] wxyz, normalised here (zero = identity)
    scales: np.ndarray,  # [N, 3]
    opacities: np.ndarray,  # [N]
    viewmat: np.ndarray,  # [4, 4]
    K: np.ndarray,  # [3, 3]
    width: int,
    height: int,
    near_plane: float = 0.01,
    far_plane: float = 1e10,
    extent: str = "opacity",
) -> Projected:
    """Float64 EWA projection of the Gaussians whose radius box reaches the image (inputs checked).

    ``extent`` is the radius rule: "opacity" (the default) reaches as far as alpha >= 1/255 can, so no
    pixel a Gaussian contributes to is cut; "3sigma" is gsplat's fixed 3-sigma box, which cuts the
    faint tails of opaque Gaussians (alpha up to o exp(-4.5) = 0.011 o at the box's edge)."""
    if extent not in EXTENT_RULES:
        raise ValueError(f"extent: expected one of {EXTENT_RULES}, got {extent!r}")
    vm = np.asarray(viewmat, dtype=np.float64)
    Kd = np.asarray(K, dtype=np.float64)
    Rv, tv = vm[:3, :3], vm[:3, 3]
    # 0. a float32 pre-filter, generous enough never to drop a Gaussian the exact float64 tests keep,
    # so Gaussians the view does not need cost a few float32 passes
    ids = _prefilter(means, scales, opacities, Rv, tv, Kd, width, height, near_plane, far_plane)
    sub = None if len(ids) == len(means) else ids  # None: every Gaussian, nothing gathered
    # 1. centre depth and opacity (the opacity cull compares float32 values, like gsplat)
    mc = Rv @ _take(means, sub).T + tv[:, None]  # [3, M] camera coordinates
    o32 = np.asarray(opacities if sub is None else np.take(opacities, sub), dtype=_F32)
    kept = (mc[2] >= near_plane) & (mc[2] <= far_plane) & (o32 >= _F32(ALPHA_THRESHOLD))
    if not kept.all():
        sel = np.flatnonzero(kept)
        ids, mc = ids[sel], mc[:, sel]
        sub = ids
    # 2. covariances (factored, :func:`_conic_terms`), the Cholesky conic and the radius box
    p00, p11, s01, cross2, jx, jy = _conic_terms(mc, quats, scales, sub, Rv, Kd, width, height)
    tz = mc[2]
    u = (Kd[0, 0] * mc[0] + Kd[0, 1] * mc[1] + Kd[0, 2] * tz) / tz  # gsplat: K[:2] @ m / z
    v = (Kd[1, 0] * mc[0] + Kd[1, 1] * mc[1] + Kd[1, 2] * tz) / tz
    s00, s11 = p00 + EPS2D, p11 + EPS2D
    det = EPS2D * EPS2D + EPS2D * (p00 + p11) + cross2
    sd11 = np.sqrt(s11)
    chol = np.stack([np.sqrt(s11 / det), -s01 / (np.sqrt(det) * sd11), 1.0 / sd11])
    ext = _extent(_take(opacities, sub), extent)
    radii = np.stack([np.ceil(ext * np.sqrt(s00)), np.ceil(ext * sd11)])
    ok = ((det > 0) & ((radii[0] > 0) | (radii[1] > 0))
          & (u + radii[0] > 0) & (u - radii[0] < width) & (v + radii[1] > 0) & (v - radii[1] < height))
    means2d = np.stack([u, v])
    if ok.all():
        return Projected(ids, means2d, chol, tz, radii)
    sel = np.flatnonzero(ok)
    return Projected(ids[sel], means2d[:, sel], chol[:, sel], tz[sel], radii[:, sel])


def _conic_terms(mc: np.ndarray, quats: np.ndarray, scales: np.ndarray, sub: np.ndarray | None, Rv: np.ndarray,
                 Kd: np.ndarray, width: int, height: int) -> tuple[np.ndarray, ...]:
    """The 2D covariance N N^T of the Gaussians at camera coordinates mc [3, M] (rows ``sub`` of the
    inputs, None: all) in factored form. -> p00 = |n0|^2, p11 = |n1|^2, s01 = n0 . n1, cross2 = |n0 x n1|^2,
    and the clamped x'/z, y'/z of the Jacobian, each [M] float64.

    Rows of N = J M: J = [[fx/z, 0, -fx x'/z^2], [0, fy/z, -fy y'/z^2]], M = R_view R S. An isotropic
    Gaussian (s_0 = s_1 = s_2 = s) has M M^T = s^2 R_view R_view^T whatever R, so its terms are
    quadratic forms in (1, x'/z, y'/z) with the Gram matrices of R_view's rows and of their cross
    products (sums of squares for an orthonormal R_view: nothing cancels); its quaternion is never read.
    The others get M from their quaternions."""
    fx, fy, cx, cy = Kd[0, 0], Kd[1, 1], Kd[0, 2], Kd[1, 2]
    tx, ty, tz = mc
    tan_fovx, tan_fovy = 0.5 * width / fx, 0.5 * height / fy
    jx = np.clip(tx / tz, -(cx / fx + 0.3 * tan_fovx), (width - cx) / fx + 0.3 * tan_fovx)
    jy = np.clip(ty / tz, -(cy / fy + 0.3 * tan_fovy), (height - cy) / fy + 0.3 * tan_fovy)
    sc = _take(scales, sub).T  # [3, M]
    G = Rv @ Rv.T
    C = np.stack([np.cross(Rv[0], Rv[1]), np.cross(Rv[0], Rv[2]), np.cross(Rv[1], Rv[2])])
    H = C @ C.T  # n0 x n1 = f0 f1 (C[0] - y' C[1] + x' C[2]) for an isotropic Gaussian
    f0 = (fx / tz) * sc[0]
    f1 = (fy / tz) * sc[0]
    jxx, jyy, jxy = jx * jx, jy * jy, jx * jy
    p00 = f0 * f0 * (G[0, 0] - 2 * G[0, 2] * jx + G[2, 2] * jxx)
    p11 = f1 * f1 * (G[1, 1] - 2 * G[1, 2] * jy + G[2, 2] * jyy)
    f01 = f0 * f1
    s01 = f01 * (G[0, 1] - G[0, 2] * jy - G[1, 2] * jx + G[2, 2] * jxy)
    cross2 = f01 * f01 * (H[0, 0] + H[1, 1] * jyy + H[2, 2] * jxx - 2 * H[0, 1] * jy + 2 * H[0, 2] * jx
                          - 2 * H[1, 2] * jxy)
    aniso = np.flatnonzero((sc[0] != sc[1]) | (sc[1] != sc[2]))
    if len(aniso):
        q = _take(quats, aniso if sub is None else sub[aniso])
        terms = _aniso_terms(quat_to_matrix(q), sc[:, aniso], Rv, fx / tz[aniso], fy / tz[aniso], jx[aniso], jy[aniso])
        for arr, t in zip((p00, p11, s01, cross2), terms):
            arr[aniso] = t
    return p00, p11, s01, cross2, jx, jy


def _aniso_terms(R: np.ndarray, sc: np.ndarray, Rv: np.ndarray, gx: np.ndarray, gy: np.ndarray, jx: np.ndarray,
                 jy: np.ndarray) -> tuple[np.ndarray, ...]:
    """p00, p11, s01, cross2 [A] (see :func:`_conic_terms`) of Gaussians with rotations R [A, 3, 3] and
    scales sc [3, A]; gx = fx / z, gy = fy / z. M is kept as rows over the Gaussians (Mr[r] [3, A] = row r
    of every M), so every product runs along A."""
    Mt = (R.transpose(0, 2, 1).reshape(-1, 3) @ Rv.T).reshape(-1, 3, 3) * sc.T[:, :, None]  # M^T = R^T R_view^T
    Mr = Mt.transpose(2, 1, 0)  # [3, 3, A]
    n0 = gx * (Mr[0] - jx * Mr[2])  # [3, A]
    n1 = gy * (Mr[1] - jy * Mr[2])
    p00 = n0[0] * n0[0] + n0[1] * n0[1] + n0[2] * n0[2]
    p11 = n1[0] * n1[0] + n1[1] * n1[1] + n1[2] * n1[2]
    s01 = n0[0] * n1[0] + n0[1] * n1[1] + n0[2] * n1[2]
    cross2 = (np.square(n0[1] * n1[2] - n0[2] * n1[1]) + np.square(n0[2] * n1[0] - n0[0] * n1[2])
              + np.square(n0[0] * n1[1] - n0[1] * n1[0]))  # |n0 x n1|^2
    return p00, p11, s01, cross2
