"""The numpy splat renderer (docs/design.md, "Renderer semantics"; never imports torch).

``rasterize(...)`` -> ``RenderOutput(rgb [H, W, 3], alpha [H, W], depth [H, W])``, float32 numpy
arrays; ``depth`` is the alpha-weighted sum of camera depths, not normalised. The same semantics as
``trioman.toolkit.render.rasterize`` (torch, differentiable).
"""

from trioman.runtime.render.rasterize import RenderOutput, rasterize

__all__ = ["RenderOutput", "rasterize"]
