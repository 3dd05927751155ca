"""``Gaussians``: activated 3D Gaussians in numpy, what the avatar poses, the .ply files hold and the renderer draws."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np


class Gaussians(NamedTuple):
    """Activated Gaussians, the renderer's arguments in its order (numpy float32)."""

    means: np.ndarray  # [N, 3] world (m)
    quats: np.ndarray  # [N, 4] wxyz, unit
    scales: np.ndarray  # [N, 3] activated (m)
    opacities: np.ndarray  # [N] in [0, 1]
    colors: np.ndarray  # [N, 3] in [0, 1]
