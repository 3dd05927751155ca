"""Forward kinematics and linear blend skinning in torch, for any skeleton given as arrays.

Same convention as trioman.runtime.skeleton (the numpy reference), so an avatar trains from a
subject's body.npz alone, without the body model that made it:

    G_0 = [R_0 | j_0 + trans],  G_c = G_parent [R_c | j_c - j_parent],  A_c = G_c [I | -j_c]
"""

from __future__ import annotations

import torch

from trioman.toolkit.rotations import axis_angle_to_matrix


def skinning_transforms(parents: list[int], joints: torch.Tensor, pose: torch.Tensor, trans: torch.Tensor) -> torch.Tensor:
    """A per joint. parents: J ints (parents[j] < j), joints: [J, 3], pose: [B, J, 3], trans: [B, 3] -> [B, J, 4, 4]."""
    B, J = pose.shape[:2]
    R = axis_angle_to_matrix(pose)  # [B, J, 3, 3]
    offsets = joints.clone()
    offsets[1:] = joints[1:] - joints[parents[1:]]
    t_local = offsets.expand(B, J, 3).clone()
    t_local[:, 0] = joints[0] + trans
    # Chain in index order (parents come first); lists avoid in-place ops on autograd tensors.
    rot, pos = [R[:, 0]], [t_local[:, 0]]
    for c in range(1, J):
        p = parents[c]
        rot.append(rot[p] @ R[:, c])
        pos.append(pos[p] + (rot[p] @ t_local[:, c, :, None])[..., 0])
    rot_t = torch.stack(rot, 1)  # [B, J, 3, 3]
    pos_t = torch.stack(pos, 1)  # [B, J, 3]
    A = torch.zeros(B, J, 4, 4, dtype=pose.dtype, device=pose.device)
    A[..., :3, :3] = rot_t
    A[..., :3, 3] = pos_t - (rot_t @ joints[..., None])[..., 0]
    A[..., 3, 3] = 1.0
    return A


def blend_transforms(A: torch.Tensor, skin_indices: torch.Tensor, skin_weights: torch.Tensor) -> torch.Tensor:
    """Per-point blended 3x4 transforms. A: [B, J, 4, 4], skin: [N, K] -> [B, N, 3, 4]."""
    gathered = A[:, skin_indices, :3, :]  # [B, N, K, 3, 4]
    return (gathered * skin_weights[None, :, :, None, None]).sum(2)


def apply_transforms(T: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """T: [B, N, 3, 4], points: [N, 3] or [B, N, 3] -> [B, N, 3]."""
    return (T[..., :3] @ points.expand(T.shape[0], -1, -1)[..., None])[..., 0] + T[..., 3]
