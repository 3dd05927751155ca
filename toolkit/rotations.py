"""Rotations in torch (differentiable): the torch twin of :mod:`trioman.runtime.rotations`, same names,
same rules and constants (docs/design.md, "Conventions"). Quaternions are wxyz. Batched over leading dims."""

from __future__ import annotations

import torch

from trioman.runtime.rotations import QUAT_NORM_FLOOR, SMALL_ANGLE


def axis_angle_to_matrix(aa: torch.Tensor) -> torch.Tensor:
    """Rodrigues with a Taylor branch for tiny angles (finite gradients at 0). [..., 3] -> [..., 3, 3]."""
    theta2 = (aa * aa).sum(-1)
    small = theta2 < SMALL_ANGLE * SMALL_ANGLE
    theta = torch.sqrt(torch.where(small, torch.ones_like(theta2), theta2))
    a = torch.where(small, 1 - theta2 / 6, torch.sin(theta) / theta)
    b = torch.where(small, 0.5 - theta2 / 24, (1 - torch.cos(theta)) / (theta * theta))
    x, y, z = aa.unbind(-1)
    zero = torch.zeros_like(x)
    K = torch.stack([zero, -z, y, z, zero, -x, -y, x, zero], -1).reshape(aa.shape[:-1] + (3, 3))
    eye = torch.eye(3, dtype=aa.dtype, device=aa.device).expand(K.shape)
    return eye + a[..., None, None] * K + b[..., None, None] * (K @ K)


def matrix_to_rot6d(R: torch.Tensor) -> torch.Tensor:
    """The first two columns, flattened (Zhou et al. 2019), a continuous pose feature. [..., 3, 3] -> [..., 6]."""
    return R[..., :, :2].transpose(-1, -2).reshape(R.shape[:-2] + (6,))


def matrix_to_quat(R: torch.Tensor) -> torch.Tensor:
    """Rotation (or near-rotation) matrix -> unit quaternion wxyz, w >= 0. [..., 3, 3] -> [..., 4]."""
    m = R
    diag = torch.stack([1 + m[..., 0, 0] + m[..., 1, 1] + m[..., 2, 2], 1 + m[..., 0, 0] - m[..., 1, 1] - m[..., 2, 2],
                        1 - m[..., 0, 0] + m[..., 1, 1] - m[..., 2, 2], 1 - m[..., 0, 0] - m[..., 1, 1] + m[..., 2, 2]], -1)
    cand = torch.stack([
        torch.stack([diag[..., 0], m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]], -1),
        torch.stack([m[..., 2, 1] - m[..., 1, 2], diag[..., 1], m[..., 1, 0] + m[..., 0, 1], m[..., 0, 2] + m[..., 2, 0]], -1),
        torch.stack([m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] + m[..., 0, 1], diag[..., 2], m[..., 2, 1] + m[..., 1, 2]], -1),
        torch.stack([m[..., 1, 0] - m[..., 0, 1], m[..., 0, 2] + m[..., 2, 0], m[..., 2, 1] + m[..., 1, 2], diag[..., 3]], -1),
    ], -2)
    best = diag.argmax(-1)
    q = torch.gather(cand, -2, best[..., None, None].expand(best.shape + (1, 4)))[..., 0, :]
    q = q / q.norm(dim=-1, keepdim=True).clamp_min(QUAT_NORM_FLOOR)
    return torch.where(q[..., :1] < 0, -q, q)


def quat_to_matrix(q: torch.Tensor) -> torch.Tensor:
    """Quaternion wxyz (normalised here; a zero quaternion is the identity) -> [..., 3, 3]. [..., 4] -> [..., 3, 3]."""
    norm = torch.linalg.vector_norm(q, dim=-1, keepdim=True)
    q = q / torch.where(norm > 0, norm, torch.ones_like(norm))  # zero stays zero -> R = I below
    w, x, y, z = q.unbind(-1)
    R = torch.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ], -1)
    return R.reshape(q.shape[:-1] + (3, 3))
