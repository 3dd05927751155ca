"""The numpy runtime renderer against the torch rasterizer (toolkit) on the same float32 inputs."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from trioman.bench.scenes import extreme_scene, orbit_viewmat, random_scene  # noqa: E402
from trioman.runtime.render import rasterize as rasterize_numpy  # noqa: E402
from trioman.toolkit.render import rasterize as rasterize_torch  # noqa: E402

TOL = 1e-5
KEYS = ("means", "quats", "scales", "opacities", "colors", "viewmat", "K")


def compare(scene, background=None, near_plane=0.01, **kw):
    arrays = [np.asarray(scene[k], dtype=np.float32) for k in KEYS]
    W, H = scene["width"], scene["height"]
    bg = None if background is None else np.asarray(background, dtype=np.float32)
    out_np = rasterize_numpy(*arrays, W, H, background=bg, near_plane=near_plane, **kw)
    with torch.no_grad():
        out_t = rasterize_torch(*(torch.from_numpy(a) for a in arrays), W, H,
                                background=None if bg is None else torch.from_numpy(bg), near_plane=near_plane)
    rgb, alpha, depth = (x.numpy() for x in out_t)
    err_rgb = np.abs(out_np.rgb - rgb).max()
    err_alpha = np.abs(out_np.alpha - alpha).max()
    err_depth = (np.abs(out_np.depth - depth) / (1.0 + np.abs(depth))).max()
    assert err_rgb <= TOL and err_alpha <= TOL and err_depth <= TOL, (err_rgb, err_alpha, err_depth)
    return alpha


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("size", [(40, 32), (37, 29)])
def test_random_scenes(seed, size):
    alpha = compare(random_scene(seed, n=120, width=size[0], height=size[1]), background=[0.2, 0.5, 0.9])
    assert alpha.max() > 0.9


@pytest.mark.parametrize("seed", [3, 4])
def test_posed_camera(seed):
    scene = random_scene(seed, n=150, width=64, height=48)
    scene["means"][:, 2] -= 3.5
    scene["viewmat"] = orbit_viewmat(0.4 * seed, 0.3, 3.5)
    compare(scene, background=[1.0, 1.0, 1.0])


@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.parametrize("tile_size", [4, 16])
def test_extreme_scenes(seed, tile_size):
    compare(extreme_scene(seed), background=[0.5, 0.5, 0.5], tile_size=tile_size)


def test_near_plane_and_culled_gaussians():
    scene = random_scene(8, n=60)
    scene["means"][:20, 2] = np.tile([0.5, 0.4999, 0.5001, -1.0], 5)
    scene["means"][20:30, 0] += 40.0  # off screen
    scene["opacities"][30:35] = 0.0
    scene["quats"][35:40] = 0.0
    compare(scene, near_plane=0.5)
