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

    @property
    def texels(self) -> int:
        """3 R^2: the rows of :meth:`texel_layer` (the columns of :meth:`sampling`)."""
        return 3 * self.planes.shape[2] * self.planes.shape[3]

    def _plane_coords(self, points: torch.Tensor) -> torch.Tensor:
        """points [N, 3] -> [3, N, 2] in [-1, 1]: (x, y), (x, z), (y, z) for the xy, xz and yz planes."""
        p = ((points - self.center) / self.half_size).clamp(-1, 1)
        return torch.stack([p[:, [0, 1]], p[:, [0, 2]], p[:, [1, 2]]])

    def forward(self, points: torch.Tensor) -> torch.Tensor:
        """points: [N, 3] -> features [N, 3C] (xy, xz and yz planes concatenated), the transposed view of a
        contiguous [3C, N] (grid_sample's layout: no copy either way, and a linear layer reads it as is)."""
        feats = F.grid_sample(self.planes, self._plane_coords(points)[:, None], mode="bilinear",
                              align_corners=True)  # [3, C, 1, N]
        return feats.reshape(-1, points.shape[0]).T

    @torch.no_grad()
    def sampling(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, int]:
        """points [N, 3] -> (indices [N, 12], weights [N, 12], texels): ``forward``'s bilinear sampling as a
        sparse [N, 3 R^2] matrix over the texels flattened plane, row, column (the 4 corners of each plane; a
        corner past the last texel has weight 0 and is clamped onto it)."""
        r = self.planes.shape[2]
        x = (self._plane_coords(points) + 1) * (0.5 * (r - 1))  # [3, N, 2] texel coordinates (align_corners)
        lo = x.floor().clamp(0, r - 1)
        frac = x - lo
        lo = lo.long()
        hi = (lo + 1).clamp(max=r - 1)
        base = (torch.arange(3, device=points.device) * r * r)[:, None]
        indices, weights = [], []
        for col, fc in ((lo[..., 0], 1 - frac[..., 0]), (hi[..., 0], frac[..., 0])):
            for row, fr in ((lo[..., 1], 1 - frac[..., 1]), (hi[..., 1], frac[..., 1])):
                indices.append(base + row * r + col)
                weights.append(fc * fr)
        n = points.shape[0]
        return (torch.stack(indices, -1).permute(1, 0, 2).reshape(n, 12),
                torch.stack(weights, -1).permute(1, 0, 2).reshape(n, 12), self.texels)

    def texel_layer(self, weight: torch.Tensor) -> torch.Tensor:
        """weight [H, 3C] of a linear layer on ``forward``'s features -> [3 R^2, H]: the layer (without its
        bias) applied to every texel's features of its own plane. Bilinear sampling is linear, so sampling
        these rows (:meth:`sampling`) gives the layer's output on the sampled features."""
        _, c, r, _ = self.planes.shape
        h = weight.shape[0]
        per_plane = weight.view(h, 3, c).permute(1, 2, 0)  # [3, C, H]
        return torch.bmm(self.planes.reshape(3, c, r * r).transpose(1, 2), per_plane).reshape(3 * r * r, h)
