"""Brute-force Gaussian splatting oracle (numpy, float64): every Gaussian at every pixel, written plainly.

The oracle the renderers are tested and benchmarked against (docs/design.md, "Renderer semantics", steps
1-6, followed literally), not a renderer to use. It shares the constants of
:mod:`.projection` but none of its arithmetic (no factored covariance, no Cholesky conic, no tiles, its
own quaternion conversion), so an error in either shows as a disagreement.
"""

from __future__ import annotations

import numpy as np

from trioman.runtime.render.projection import ALPHA_THRESHOLD, EPS2D, MAX_ALPHA, MAX_EXTENT, TRANSMITTANCE_THRESHOLD

F32 = np.float32
ALPHA_MIN32 = F32(ALPHA_THRESHOLD)
T_MIN32 = F32(TRANSMITTANCE_THRESHOLD)
ONE32 = F32(1.0)


def _quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """One quaternion wxyz [4] -> [3, 3], normalised; zero -> the identity."""
    n = np.sqrt(np.sum(q * q))
    if n == 0:
        return np.eye(3, dtype=q.dtype)
    w, x, y, z = q / n
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ], dtype=q.dtype)


def project_reference(means, quats, scales, opacities, viewmat, K, width, height, near_plane=0.01,
                      far_plane=1e10, dtype=np.float64):
    """Per-Gaussian projection. -> list of dicts (one per input, None where culled)."""
    means, quats, scales, opacities, viewmat, K = (np.asarray(x, dtype=dtype) for x in
                                                   (means, quats, scales, opacities, viewmat, K))
    Rv, tv = viewmat[:3, :3], viewmat[:3, 3]
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    tan_fovx, tan_fovy = 0.5 * width / fx, 0.5 * height / fy
    lim_x_pos = (width - cx) / fx + 0.3 * tan_fovx
    lim_x_neg = cx / fx + 0.3 * tan_fovx
    lim_y_pos = (height - cy) / fy + 0.3 * tan_fovy
    lim_y_neg = cy / fy + 0.3 * tan_fovy
    out = []
    for i in range(len(means)):
        mc = Rv @ means[i] + tv
        x, y, z = mc
        o = opacities[i]
        if z < near_plane or z > far_plane or F32(o) < ALPHA_MIN32:
            out.append(None)
            continue
        R = _quat_to_matrix(quats[i])
        S = np.diag(scales[i])
        Sigma = R @ S @ S.T @ R.T
        Sc = Rv @ Sigma @ Rv.T
        xc = z * min(max(x / z, -lim_x_neg), lim_x_pos)
        yc = z * min(max(y / z, -lim_y_neg), lim_y_pos)
        J = np.array([[fx / z, 0, -fx * xc / z ** 2], [0, fy / z, -fy * yc / z ** 2]], dtype=dtype)
        cov = J @ Sc @ J.T + EPS2D * np.eye(2, dtype=dtype)
        det = cov[0, 0] * cov[1, 1] - cov[0, 1] * cov[1, 0]
        mean2d = (K[:2] @ mc) / z
        extent = min(dtype(MAX_EXTENT), np.sqrt(max(dtype(0), 2 * np.log(o * 255))))
        rx, ry = np.ceil(extent * np.sqrt(cov[0, 0])), np.ceil(extent * np.sqrt(cov[1, 1]))
        if det <= 0 or (rx <= 0 and ry <= 0):
            out.append(None)
            continue
        if (mean2d[0] + rx <= 0 or mean2d[0] - rx >= width or mean2d[1] + ry <= 0 or mean2d[1] - ry >= height):
            out.append(None)
            continue
        conic = np.array([cov[1, 1] / det, -cov[0, 1] / det, cov[0, 0] / det], dtype=dtype)
        out.append(dict(mean2d=mean2d, conic=conic, depth=z, radii=(rx, ry), opacity=o, cov2d=cov))
    return out


def rasterize_reference(
    means: np.ndarray,  # [N, 3]
    quats: np.ndarray,  # [N, 4] wxyz
    scales: np.ndarray,  # [N, 3]
    opacities: np.ndarray,  # [N]
    colors: np.ndarray,  # [N, 3]
    viewmat: np.ndarray,  # [4, 4]
    K: np.ndarray,  # [3, 3]
    width: int,
    height: int,
    background: np.ndarray | None = None,  # [3]
    near_plane: float = 0.01,
    far_plane: float = 1e10,
    dtype=np.float64,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """-> (rgb [H, W, 3], alpha [H, W], depth [H, W]) in ``dtype``. sigma < 0 is skipped (gsplat's guard);
    the stop test runs on a float32 T (``T32``) exactly as written, the colour sums on ``dtype`` values of
    alpha and T (np.longdouble for extra precision on extreme scenes)."""
    colors = np.asarray(colors, dtype=dtype).reshape(-1, 3)
    bg = np.zeros(3, dtype=dtype) if background is None else np.asarray(background, dtype=dtype)
    proj = project_reference(means, quats, scales, opacities, viewmat, K, width, height, near_plane, far_plane, dtype)
    px = (np.arange(width, dtype=dtype) + dtype(0.5))[None, :] * np.ones((height, 1), dtype=dtype)
    py = (np.arange(height, dtype=dtype) + dtype(0.5))[:, None] * np.ones((1, width), dtype=dtype)
    C = np.zeros((height, width, 3), dtype=dtype)
    D = np.zeros((height, width), dtype=dtype)
    T = np.ones((height, width), dtype=dtype)
    T32 = np.ones((height, width), dtype=F32)
    done = np.zeros((height, width), dtype=bool)
    visible = [i for i, p in enumerate(proj) if p is not None]
    order = sorted(visible, key=lambda i: (proj[i]["depth"], i))  # front to back, ties by index
    for i in order:
        p = proj[i]
        mx, my = p["mean2d"]
        rx, ry = p["radii"]
        A, B, Cc = p["conic"]
        dx, dy = px - mx, py - my
        in_box = (np.abs(dx) <= rx) & (np.abs(dy) <= ry)
        sigma = 0.5 * (A * dx * dx + Cc * dy * dy) + B * dx * dy
        alpha = np.minimum(dtype(MAX_ALPHA), p["opacity"] * np.exp(-sigma))
        a32 = alpha.astype(F32)
        use = in_box & ~done & (sigma >= 0) & (a32 >= ALPHA_MIN32)
        next_T32 = T32 * (ONE32 - a32)  # float32 arithmetic
        stop = use & (next_T32 <= T_MIN32)
        done |= stop
        use &= ~stop
        w = np.where(use, alpha * T, 0)
        C += w[..., None] * colors[i]
        D += w * p["depth"]
        T = np.where(use, T * (1 - alpha), T)
        T32 = np.where(use, next_T32, T32)
    rgb = C + T[..., None] * bg
    return rgb, 1 - T, D
