"""Differentiable Gaussian splatting (torch): CPU tile rasterizer, gsplat on CUDA.

``rasterize(...)`` -> ``RenderOutput(rgb [H, W, 3], alpha [H, W], depth [H, W])`` with the semantics of
docs/design.md, "Renderer semantics" (gsplat's); ``project_gaussians(...)`` -> ``Projection`` (means2d, conics,
depths, radii, visible), the projection step on its own. ``depth`` is the alpha-weighted sum of camera
depths, not normalised.
"""

from trioman.toolkit.render.projection import Projection, project_gaussians
from trioman.toolkit.render.rasterize import RenderOutput, rasterize

__all__ = ["Projection", "RenderOutput", "project_gaussians", "rasterize"]
