"""Scene generators of the renderer tests and the stability benchmark (numpy only: usable without torch)."""

from __future__ import annotations

import numpy as np

from trioman.runtime import cameras


def random_scene(seed: int, n: int = 60, width: int = 40, height: int = 32):
    """Gaussians in front of an identity camera, mixed sizes, rotations and opacities."""
    rng = np.random.default_rng(seed)
    means = rng.uniform([-1.0, -1.0, 2.0], [1.0, 1.0, 5.0], (n, 3))
    quats = rng.normal(size=(n, 4))
    scales = np.exp(rng.uniform(np.log(0.01), np.log(0.4), (n, 3)))
    opacities = rng.uniform(0.0, 1.0, n)
    colors = rng.uniform(0.0, 1.0, (n, 3))
    f = 0.8 * width
    K = np.array([[f, 0.0, width / 2 + 0.3], [0.0, 1.1 * f, height / 2 - 0.7], [0.0, 0.0, 1.0]])
    viewmat = np.eye(4)
    return dict(means=means, quats=quats, scales=scales, opacities=opacities, colors=colors, viewmat=viewmat, K=K,
                width=width, height=height)


def orbit_viewmat(azimuth: float, elevation: float, distance: float) -> np.ndarray:
    """Camera looking at the origin (OpenCV axes), z-up world."""
    return cameras.orbit_viewmat(np.zeros(3), azimuth, elevation, distance)


def random_rotations(rng, n):
    q = rng.normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def extreme_scene(seed: int):
    """Scales 1e-6 .. 1e2 m, needles and discs with anisotropy 1e6, huge faint Gaussians, thin ones
    crossing the image from 5 cm in front of the camera."""
    rng = np.random.default_rng(seed)
    W, H = 40, 36
    parts = []
    n = 40  # tiny to medium, isotropic-ish
    parts.append((rng.uniform([-1, -1, 1], [1, 1, 10], (n, 3)), np.exp(rng.uniform(np.log(1e-6), np.log(1e-1), (n, 3))),
                  rng.uniform(0, 1, n)))
    n = 30  # anisotropy 1e6: needles (1, 1e-6, 1e-6) and discs (1, 1, 1e-6), 0.1 .. 3 m long
    shape = np.where(rng.uniform(size=(n, 1)) < 0.5, [1.0, 1e-6, 1e-6], [1.0, 1.0, 1e-6])
    length = np.exp(rng.uniform(np.log(0.1), np.log(3), (n, 1)))
    parts.append((rng.uniform([-1, -1, 2], [1, 1, 6], (n, 3)), shape * length, rng.uniform(0.3, 1, n)))
    n = 5  # 10 .. 100 m, faint
    parts.append((rng.uniform([-5, -5, 5], [5, 5, 50], (n, 3)), np.exp(rng.uniform(np.log(10), np.log(100), (n, 3))),
                  rng.uniform(0.02, 0.1, n)))
    n = 4  # 100 m long, 0.1 mm thick, 5 .. 20 cm in front of the camera
    near = np.c_[rng.uniform(-0.02, 0.02, (n, 2)), rng.uniform(0.05, 0.2, n)]
    parts.append((near, np.tile([1e2, 1e-4, 1e-4], (n, 1)), rng.uniform(0.3, 0.8, n)))
    means, scales, opacities = (np.concatenate(x) for x in zip(*parts))
    n = len(means)
    f = 0.8 * W
    return dict(means=means, quats=random_rotations(rng, n), scales=scales, opacities=opacities,
                colors=rng.uniform(0, 1, (n, 3)), viewmat=np.eye(4),
                K=np.array([[f, 0.0, W / 2 + 0.3], [0.0, f, H / 2 - 0.2], [0.0, 0.0, 1.0]]), width=W, height=H)
