"""A learned triplane (3 x C x R x R) sampled bilinearly at canonical points."""

from __future__ import annotations

import torch
import torch.nn.functional as F


class Triplane(torch.nn.Module):
    """Features for points inside an axis-aligned cube (``center`` +- ``half_size`` metres)."""

    def __init__(self, channels: int, resolution: int, center: torch.Tensor, half_size: float, init_std: float = 0.1):
        super().__init__()
        planes = torch.randn(3, channels, resolution, resolution) * init_std
        self.planes = torch.nn.Parameter(planes)
        self.register_buffer("center", center.float().clone())
        self.half_size = float(half_size)

    @property
    def out_dim(self) -> int:
        return 3 * self.planes.shape[1]

    def forward(self, points: torch.Tensor) -> torch.Tensor:
        """points: [N, 3] -> features [N, 3C] (xy, xz and yz planes concatenated), the transposed view of a
        contiguous [3C, N] (grid_sample's layout: no copy either way, and a linear layer reads it as is)."""
        p = ((points - self.center) / self.half_size).clamp(-1, 1)
        coords = torch.stack([p[:, [0, 1]], p[:, [0, 2]], p[:, [1, 2]]])  # [3, N, 2]
        feats = F.grid_sample(self.planes, coords[:, None], mode="bilinear", align_corners=True)  # [3, C, 1, N]
        return feats.reshape(-1, points.shape[0]).T
