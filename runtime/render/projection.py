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
    """Float64 screen-space values of the M Gaussians that reach the image, in input order."""

    ids: np.ndarray  # [M] int64 indices into the N inputs
    means2d: np.ndarray  # [M, 2] pixels
    chol: np.ndarray  # [M, 3] (a, b, c): sigma = 0.5 ((a dx + b dy)^2 + (c dy)^2)
    depths: np.ndarray  # [M] camera z of the centre
    radii: np.ndarray  # [M, 2] whole numbers: the box |dx| <= r_x, |dy| <= r_y


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


def _rows(x: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """x[ids] in float64."""
    return np.take(x, ids, axis=0).astype(np.float64)


EXTENT_RULES = ("opacity", "3sigma")  # see project()


def _extent(opacities: np.ndarray, rule: str = "opacity") -> np.ndarray:
    """Sigmas of the radius box [M] -> [M]. "opacity": min(3.33, sqrt(2 ln(255 o))) (0 below o = 1/255),
    where alpha >= 1/255 can reach; "3sigma": 3 for every Gaussian (gsplat's radius rule)."""
    if rule == "3sigma":
        return np.full(len(opacities), 3.0)
    with np.errstate(divide="ignore"):
        return np.minimum(np.sqrt(np.maximum(2.0 * np.log(opacities * 255.0), 0.0)), MAX_EXTENT)


def _bound_radii(smax: np.ndarray, z: np.ndarray, jx: np.ndarray, jy: np.ndarray, fx: float, fy: float,
                 rv_norm: float, extent: np.ndarray) -> np.ndarray:
    """Upper bounds of the radii [M, 2] from the largest scale alone.

    Row 0 of N = J R_view R S is (fx / z) (e_x - (x'/z) e_z)^T R_view R S, whose norm is at most
    (fx / z) sqrt(1 + (x'/z)^2) |R_view|_2 max(s) (R orthonormal); row 1 alike. The margin covers
    rounding, so a Gaussian whose bounded box is off screen is off screen.
    """
    g = rv_norm * smax / z
    var_x = (fx * g) ** 2 * (1.0 + jx * jx) + EPS2D
    var_y = (fy * g) ** 2 * (1.0 + jy * jy) + EPS2D
    return np.stack([np.ceil(extent * np.sqrt(var_x)), np.ceil(extent * np.sqrt(var_y))], -1) * (1 + 1e-9) + 1.0


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
    x, y, z, scale = np.take(x, ids), np.take(y, ids), np.take(z, ids), np.take(scale, ids)
    z0 = np.maximum(z - scale, _F32(near) * _F32(0.5))  # the smallest depth the centre may have
    z1 = z0 + 2 * scale  # the largest
    fx, fy, cx, cy = (_F32(v) for v in (Kd[0, 0], Kd[1, 1], Kd[0, 2], Kd[1, 2]))
    sc = np.asarray(scales, dtype=_F32)
    smax = np.maximum(np.maximum(np.take(sc[:, 0], ids), np.take(sc[:, 1], ids)), np.take(sc[:, 2], ids))
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
    f64 = np.float64
    vm = np.asarray(viewmat, dtype=f64)
    Kd = np.asarray(K, dtype=f64)
    Rv, tv = vm[:3, :3], vm[:3, 3]
    fx, fy, cx, cy = Kd[0, 0], Kd[1, 1], Kd[0, 2], Kd[1, 2]
    # 0. a float32 pre-filter, generous enough never to drop a Gaussian the exact float64 tests keep,
    # so Gaussians the view does not need cost a few float32 passes
    ids = _prefilter(means, scales, opacities, Rv, tv, Kd, width, height, near_plane, far_plane)
    # 1. centre depth and opacity (the opacity cull compares float32 values, like gsplat)
    z_all = _rows(means, ids) @ Rv[2] + tv[2]
    o32 = np.take(np.asarray(opacities, dtype=_F32), ids)
    ids = ids[(z_all >= near_plane) & (z_all <= far_plane) & (o32 >= _F32(ALPHA_THRESHOLD))]
    mc = _rows(means, ids) @ Rv.T + tv
    tx, ty, tz = mc.T
    tan_fovx, tan_fovy = 0.5 * width / fx, 0.5 * height / fy
    jx = np.clip(tx / tz, -(cx / fx + 0.3 * tan_fovx), (width - cx) / fx + 0.3 * tan_fovx)
    jy = np.clip(ty / tz, -(cy / fy + 0.3 * tan_fovy), (height - cy) / fy + 0.3 * tan_fovy)
    mean2d = (mc[:, :2] @ Kd[:2, :2].T + Kd[:2, 2] * tz[:, None]) / tz[:, None]  # gsplat: K[:2] @ m / z
    extent = _extent(_rows(opacities, ids), extent)

    def on_screen(m2, r):
        return ((m2[:, 0] + r[:, 0] > 0) & (m2[:, 0] - r[:, 0] < width)
                & (m2[:, 1] + r[:, 1] > 0) & (m2[:, 1] - r[:, 1] < height))

    # 2. conservative screen bound from the largest scale
    smax = _rows(scales, ids).max(1)
    kept = on_screen(mean2d, _bound_radii(smax, tz, jx, jy, fx, fy, np.linalg.norm(Rv, 2), extent))
    ids, tz, jx, jy, mean2d, extent = _where(kept, ids, tz, jx, jy, mean2d, extent)
    # 3. covariances of the survivors; rows of N = J M: J = [[fx/z, 0, -fx x'/z^2], [0, fy/z, -fy y'/z^2]],
    # M = R_view R S. Kept as rows over the Gaussians (Mr[r] [3, M] = row r of every M), so every
    # product runs along M. Isotropic Gaussians (s_0 = s_1 = s_2 = s) have Sigma = s^2 I whatever R:
    # M = s R_view, exactly the same N N^T, so their quaternions are never converted.
    sc = _rows(scales, ids)
    iso = (sc[:, 0] == sc[:, 1]) & (sc[:, 1] == sc[:, 2])
    aniso = np.flatnonzero(~iso)
    Mr = Rv[:, :, None] * sc[:, 0]  # [3, 3, M]: every Gaussian's isotropic value
    if len(aniso):
        R = quat_to_matrix(_rows(quats, ids[aniso]))  # M^T = R^T R_view^T, its rows scaled by s
        Mt = (R.transpose(0, 2, 1).reshape(-1, 3) @ Rv.T).reshape(-1, 3, 3) * sc[aniso, :, None]
        Mr[:, :, aniso] = Mt.transpose(2, 1, 0)
    n0 = (fx / tz) * (Mr[0] - jx * Mr[2])  # [3, M]
    n1 = (fy / tz) * (Mr[1] - jy * Mr[2])
    p00 = n0[0] * n0[0] + n0[1] * n0[1] + n0[2] * n0[2]
    p11 = n1[0] * n1[0] + n1[1] * n1[1] + n1[2] * n1[2]
    s00, s11, s01 = p00 + EPS2D, p11 + EPS2D, n0[0] * n1[0] + n0[1] * n1[1] + n0[2] * n1[2]
    cross2 = (np.square(n0[1] * n1[2] - n0[2] * n1[1]) + np.square(n0[2] * n1[0] - n0[0] * n1[2])
              + np.square(n0[0] * n1[1] - n0[1] * n1[0]))  # |n0 x n1|^2
    det = EPS2D * EPS2D + EPS2D * (p00 + p11) + cross2
    chol = np.stack([np.sqrt(s11 / det), -s01 / np.sqrt(det * s11), 1.0 / np.sqrt(s11)], -1)
    radii = np.stack([np.ceil(extent * np.sqrt(s00)), np.ceil(extent * np.sqrt(s11))], -1)
    ok = (det > 0) & ((radii[:, 0] > 0) | (radii[:, 1] > 0)) & on_screen(mean2d, radii)
    return Projected(*_where(ok, ids, mean2d, chol, tz, radii))


def _where(keep: np.ndarray, *arrays: np.ndarray) -> list[np.ndarray]:
    """The rows of ``arrays`` where ``keep`` [M] is True, or the arrays themselves when it is True everywhere
    (no copies when nothing is culled)."""
    if keep.all():
        return list(arrays)
    sel = np.flatnonzero(keep)
    return [a[sel] for a in arrays]
