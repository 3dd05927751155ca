"""The EWA projection of 3D Gaussians to the image in float64 with autograd (torch; the twin of
``trioman.runtime.render.projection``, whose constants and checks it uses): docs/design.md, "Renderer
semantics" and its "How the renderers compute it" (factored covariance, Cholesky conic).
"""

from __future__ import annotations

from typing import NamedTuple

import torch

# The semantics' constants and input rules, defined once for both renderers (runtime/render/projection.py).
from trioman.runtime.render.projection import (  # noqa: F401 (constants re-exported for the toolkit renderer)
    ALPHA_THRESHOLD,
    EPS2D,
    MAX_ALPHA,
    MAX_EXTENT,
    TRANSMITTANCE_THRESHOLD,
    check_shape,
    check_size,
    check_values,
)
from trioman.toolkit.rotations import quat_to_matrix


class Projection(NamedTuple):
    """Per-Gaussian screen-space quantities; entries of culled Gaussians are 0 (depth excepted)."""

    means2d: torch.Tensor  # [N, 2] pixels
    conics: torch.Tensor  # [N, 3] (A, B, C) of the inverse 2D covariance
    depths: torch.Tensor  # [N] camera z of the centre (every Gaussian)
    radii: torch.Tensor  # [N, 2] int32, 0 where culled
    visible: torch.Tensor  # [N] bool


class Projected(NamedTuple):
    """The rasterizer's view: float64 values of the M visible Gaussians only (autograd attached)."""

    ids: torch.Tensor  # [M] int64 indices into the N inputs
    means2d: torch.Tensor  # [M, 2]
    chol: torch.Tensor  # [M, 3] (a, b, c): sigma = 0.5 ((a dx + b dy)^2 + (c dy)^2)
    conics: torch.Tensor  # [M, 3] (A, B, C)
    depths: torch.Tensor  # [M]
    radii: torch.Tensor  # [M, 2] float64 whole numbers (no grad)
    z_all: torch.Tensor  # [N] camera z of every Gaussian (detached)


# --------------------------------------------------------------------------------------------
# input checks


def _check_tensor(name: str, t, shape: tuple, device=None) -> torch.Tensor:
    """shape: ints, or None for 'any'. Returns the tensor; raises ValueError naming ``name``."""
    if not isinstance(t, torch.Tensor):
        raise ValueError(f"{name}: expected a torch.Tensor, got {type(t).__name__}")
    if not t.dtype.is_floating_point:
        raise ValueError(f"{name}: expected a floating-point tensor, got dtype {t.dtype}")
    check_shape(name, tuple(t.shape), shape)
    if device is not None and t.device != device:
        raise ValueError(f"{name}: on device {t.device}, expected {device} like means")
    bad = int((~torch.isfinite(t.detach())).sum())
    if bad:
        raise ValueError(f"{name}: {bad} of {t.numel()} values are NaN or Inf")
    return t


def _numpy(t: torch.Tensor | None):
    return None if t is None else t.detach().cpu().numpy()


def check_inputs(means, quats, scales, opacities, colors, viewmat, K, width, height, background=None,
                 near_plane: float = 0.01, far_plane: float = 1e10):
    """Validate the rasterizer's inputs (ValueError naming the argument and the count). -> (N, W, H).

    The torch checks (type, dtype, device) come first, then the rules shared with the numpy renderer
    (:func:`trioman.runtime.render.projection.check_values`)."""
    width = check_size("width", width)
    height = check_size("height", height)
    if not isinstance(means, torch.Tensor):
        raise ValueError(f"means: expected a torch.Tensor, got {type(means).__name__}")
    n = means.shape[0] if means.dim() >= 1 else -1
    dev = means.device
    _check_tensor("means", means, (None, 3))
    _check_tensor("quats", quats, (n, 4), dev)
    _check_tensor("scales", scales, (n, 3), dev)
    if opacities is not None:
        _check_tensor("opacities", opacities, (n,), dev)
    if colors is not None:
        _check_tensor("colors", colors, (n, 3), dev)
    _check_tensor("viewmat", viewmat, (4, 4), dev)
    _check_tensor("K", K, (3, 3), dev)
    if background is not None:
        _check_tensor("background", background, (3,), dev)
    check_values(_numpy(scales), _numpy(opacities), _numpy(K), near_plane, far_plane)
    return n, width, height


# --------------------------------------------------------------------------------------------
# projection


def take_rows(x: torch.Tensor, ids: torch.Tensor) -> torch.Tensor:
    """x[ids] for sorted unique ids [M] (torch.nonzero's), or x itself when they select every row: the same
    values without a gather and its backward's scatter (when nothing is culled)."""
    return x if ids.numel() == x.shape[0] else x[ids]


def project(means, quats, scales, opacities, viewmat, K, width: int, height: int,
            near_plane: float = 0.01, far_plane: float = 1e10, eps2d: float = EPS2D) -> Projected:
    """Float64 projection of the visible Gaussians (docs/design.md, "How the renderers compute it").
    ``opacities`` None: extent 3.33, no opacity cull (the rule of gsplat's pure-torch reference)."""
    f64 = torch.float64
    vm = viewmat.to(f64)
    Kd = K.to(f64)
    Rv, tv = vm[:3, :3], vm[:3, 3]
    mc_all = means.to(f64) @ Rv.T + tv  # [N, 3]
    z_all = mc_all[:, 2].detach()
    keep = (z_all >= near_plane) & (z_all <= far_plane)
    if opacities is not None:  # the opacity cull compares float32 values, like gsplat
        keep &= opacities.detach().float() >= torch.tensor(ALPHA_THRESHOLD, dtype=torch.float32)
    ids = torch.nonzero(keep).squeeze(1)
    mc = take_rows(mc_all, ids)
    sc = take_rows(scales, ids)
    tx, ty, tz = mc.unbind(-1)
    fx, fy, cx, cy = Kd[0, 0], Kd[1, 1], Kd[0, 2], Kd[1, 2]
    tan_fovx, tan_fovy = 0.5 * width / fx, 0.5 * height / fy
    lim_x_pos = (width - cx) / fx + 0.3 * tan_fovx
    lim_x_neg = cx / fx + 0.3 * tan_fovx
    lim_y_pos = (height - cy) / fy + 0.3 * tan_fovy
    lim_y_neg = cy / fy + 0.3 * tan_fovy
    ax = torch.clamp(tx / tz, min=-lim_x_neg, max=lim_x_pos)  # x'/z: the clamped ratio J uses
    ay = torch.clamp(ty / tz, min=-lim_y_neg, max=lim_y_pos)
    # J = [[fx/z, 0, -fx x'/z^2], [0, fy/z, -fy y'/z^2]]; Sigma_2d = N N^T + eps2d I with N = J M, Sigma_c = M M^T
    if scales.stride(1) == 0 and not quats.requires_grad:
        # one scale per Gaussian broadcast to three axes (an expand): Sigma_c = s^2 I for any rotation, so
        # N N^T = s^2 J J^T and the quaternions are not read
        k = sc[:, 0].to(f64) / tz
        kx, ky = fx * k, fy * k
        p00, p11 = kx * kx * (1 + ax * ax), ky * ky * (1 + ay * ay)
        s01 = kx * ky * ax * ay
        kxy = kx * ky
        cross2 = kxy * kxy * (ax * ax + ay * ay + 1)  # |n0 x n1|^2, n0 x n1 = fx fy k^2 (x'/z, y'/z, 1)
    else:
        R = quat_to_matrix(take_rows(quats, ids).to(f64))
        M = Rv @ (R * sc.to(f64)[:, None, :])  # [M, 3, 3] camera-frame factor: Sigma_c = M M^T
        n0 = (fx / tz)[:, None] * (M[:, 0, :] - ax[:, None] * M[:, 2, :])  # rows of N
        n1 = (fy / tz)[:, None] * (M[:, 1, :] - ay[:, None] * M[:, 2, :])
        p00, p11, s01 = (n0 * n0).sum(-1), (n1 * n1).sum(-1), (n0 * n1).sum(-1)
        cross = torch.linalg.cross(n0, n1)
        cross2 = (cross * cross).sum(-1)
    s00, s11 = p00 + eps2d, p11 + eps2d
    det = eps2d * eps2d + eps2d * (p00 + p11) + cross2
    conics = torch.stack([s11 / det, -s01 / det, s00 / det], -1)
    chol = torch.stack([torch.sqrt(s11 / det), -s01 / torch.sqrt(det * s11), 1.0 / torch.sqrt(s11)], -1)
    mean2d = (mc[:, :2] @ Kd[:2, :2].T + Kd[:2, 2] * tz[:, None]) / tz[:, None]  # gsplat: K[:2] @ m / z
    with torch.no_grad():
        if opacities is None:
            extent = torch.full_like(tz, MAX_EXTENT)
        else:
            o = take_rows(opacities, ids).detach().to(f64)
            extent = torch.sqrt(torch.clamp(2.0 * torch.log(o * 255.0), min=0.0)).clamp(max=MAX_EXTENT)
        radii = torch.stack([torch.ceil(extent * torch.sqrt(s00.detach())),
                             torch.ceil(extent * torch.sqrt(s11.detach()))], -1)
        m2 = mean2d.detach()
        ok = (det.detach() > 0) & ((radii[:, 0] > 0) | (radii[:, 1] > 0))
        ok &= (m2[:, 0] + radii[:, 0] > 0) & (m2[:, 0] - radii[:, 0] < width)
        ok &= (m2[:, 1] + radii[:, 1] > 0) & (m2[:, 1] - radii[:, 1] < height)
        sel = torch.nonzero(ok).squeeze(1)
    return Projected(ids=take_rows(ids, sel), means2d=take_rows(mean2d, sel), chol=take_rows(chol, sel),
                     conics=take_rows(conics, sel), depths=take_rows(tz, sel), radii=take_rows(radii, sel), z_all=z_all)


def project_gaussians(
    means: torch.Tensor,  # [N, 3]
    quats: torch.Tensor,  # [N, 4] wxyz
    scales: torch.Tensor,  # [N, 3]
    opacities: torch.Tensor | None,  # [N] or None (fixed 3.33-sigma extent, no opacity cull)
    viewmat: torch.Tensor,  # [4, 4]
    K: torch.Tensor,  # [3, 3]
    width: int,
    height: int,
    near_plane: float = 0.01,
    far_plane: float = 1e10,
) -> Projection:
    """Project Gaussians to the image: means2d, conics, depths, radii (int32) and the visible mask.

    Differentiable (float64 inside, returned in the dtype of ``means``). Culled Gaussians (centre
    depth outside [near, far], opacity < 1/255, box entirely off screen) have radii 0 and zero
    means2d/conics; ``depths`` is the camera z of every Gaussian.
    """
    n, width, height = check_inputs(means, quats, scales, opacities, None, viewmat, K, width, height,
                                    near_plane=near_plane, far_plane=far_plane)
    p = project(means, quats, scales, opacities, viewmat, K, width, height, near_plane, far_plane)
    dt = means.dtype
    means2d = means.new_zeros(n, 2, dtype=torch.float64).index_copy(0, p.ids, p.means2d)
    conics = means.new_zeros(n, 3, dtype=torch.float64).index_copy(0, p.ids, p.conics)
    z = (means.to(torch.float64) @ viewmat.to(torch.float64)[2, :3]) + viewmat.to(torch.float64)[2, 3]
    radii = torch.zeros(n, 2, dtype=torch.int32, device=means.device)
    radii[p.ids] = p.radii.clamp(max=2**31 - 1).to(torch.int32)
    visible = torch.zeros(n, dtype=torch.bool, device=means.device)
    visible[p.ids] = True
    return Projection(means2d.to(dt), conics.to(dt), z.to(dt), radii, visible)
