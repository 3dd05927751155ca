"""The avatar's architecture settings (toolkit/avatar/model.py), standard-library only so that training configs
are read without torch."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class AvatarConfig:
    subdivisions: int = 0  # midpoint subdivisions of the body mesh
    keep: float = 1.0  # fraction of the points kept (seeded subset), for speed
    triplane_channels: int = 32
    triplane_res: int = 128
    triplane_half_size: float = 1.0  # metres: the triplane covers a 2 m cube about the body centre
    hidden: int = 128
    anisotropic: bool = False
    pose_dependent: bool = True
    # Where the pose-dependent MLPs run: None, at every Gaussian; L, at the vertices of the mesh after L of the
    # `subdivisions` midpoint steps (the triplane sampled there), their deltas carried to the Gaussians by the
    # linear map that makes the Gaussians' canonical points from those vertices.
    pose_subdivisions: int | None = None
    knn: int = 6  # neighbours for the Laplacian regularisers and the initial scale
    scale_init: float = 0.75  # initial Gaussian scale, in units of the mean neighbour distance
    point_colors: bool = False  # a free colour logit per Gaussian on top of the triplane MLP's (detail below a cell)
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("triplane_channels", "triplane_res", "hidden", "knn"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name}: must be >= 1, got {getattr(self, name)}")
        level = self.pose_subdivisions
        if level is not None and (isinstance(level, bool) or not isinstance(level, int) or not 0 <= level <= self.subdivisions):
            raise ValueError(f"pose_subdivisions: must be None or an integer in [0, subdivisions = {self.subdivisions}], "
                             f"got {level!r}")
