"""Textured, shaded mesh rendering for synthetic subjects (numpy, z-buffer mesh rasterizer).

Never the splat renderer: ground truth must not come from the model family being evaluated.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from trioman.runtime.mesh_raster import interpolate, rasterize_mesh, sample_texture, vertex_normals
from trioman.runtime.skeleton import SkinnedMesh


@dataclass(frozen=True)
class Lighting:
    """Ambient + a world-fixed key light + a fill light from the camera."""

    ambient: float = 0.42
    key: float = 0.43
    fill: float = 0.2
    key_dir: tuple[float, float, float] = (0.35, -0.55, 0.76)  # towards the light, world


def render_textured(
    mesh: SkinnedMesh,
    vertices: np.ndarray,  # [V, 3] posed, world
    texture: np.ndarray,  # [Ht, Wt, 3]
    viewmat: np.ndarray,  # [4, 4]
    K: np.ndarray,  # [3, 3]
    width: int,
    height: int,
    supersample: int = 2,
    lighting: Lighting = Lighting(),
) -> tuple[np.ndarray, np.ndarray]:
    """Render with ``supersample``^2 samples per pixel. -> rgb [H, W, 3] on black, mask [H, W] coverage."""
    ss = int(supersample)
    if ss < 1:
        raise ValueError(f"supersample: must be >= 1, got {supersample}")
    K_ss = np.array(K, dtype=np.float64)
    K_ss[:2] *= ss  # continuous pixel coordinates scale with the image
    frags = rasterize_mesh(vertices, mesh.faces, viewmat, K_ss, width * ss, height * ss)
    covered = frags.face_id >= 0
    uv = interpolate(frags, mesh.uvs, mesh.uv_faces)
    albedo = sample_texture(texture, uv)
    n = interpolate(frags, vertex_normals(vertices, mesh.faces), mesh.faces)
    n /= np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-8)
    key = np.asarray(lighting.key_dir) / np.linalg.norm(lighting.key_dir)
    to_camera = -viewmat[2, :3]  # camera forward axis in world, reversed
    shade = lighting.ambient + lighting.key * np.clip(n @ key, 0, None) + lighting.fill * np.clip(n @ to_camera, 0, None)
    rgb = np.clip(albedo * shade[..., None], 0.0, 1.0) * covered[..., None]
    mask = covered.astype(np.float32)
    if ss > 1:  # box filter down to the output size
        rgb = rgb.reshape(height, ss, width, ss, 3).mean(axis=(1, 3))
        mask = mask.reshape(height, ss, width, ss).mean(axis=(1, 3))
    return rgb.astype(np.float32), mask.astype(np.float32)
