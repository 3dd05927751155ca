"""Body normal maps: the Refiner's geometry condition I_g (paper 3.2.4 and 3.2.5), ``normal_map`` and
``body_normal_map``. The encoding: docs/formats.md, "Triplets".
"""

from __future__ import annotations

from typing import NamedTuple, Sequence

import numpy as np

from trioman.runtime.mesh_raster import interpolate, rasterize_mesh, vertex_normals
from trioman.runtime.skeleton import SkinnedMesh

__all__ = ["NormalMap", "normal_map", "body_normal_map", "CV_TO_NORMAL_MAP"]

# OpenCV camera axes (x right, y down, z forward) -> normal-map axes (x right, y up, z to camera).
CV_TO_NORMAL_MAP = np.diag([1.0, -1.0, -1.0])
_TINY = 1e-12


class NormalMap(NamedTuple):
    rgb: np.ndarray  # [H, W, 3] float32 in [0, 1]
    mask: np.ndarray  # [H, W] bool, True where the mesh covers the pixel centre


def _background(value: float | Sequence[float]) -> np.ndarray:
    try:
        bg = np.broadcast_to(np.asarray(value, dtype=np.float64), (3,))
    except (TypeError, ValueError):
        raise ValueError(f"background: expected a number or 3 numbers in [0, 1], got {value!r}") from None
    if not np.all((bg >= 0) & (bg <= 1)):
        raise ValueError(f"background: values must lie in [0, 1], got {bg.tolist()}")
    return bg.astype(np.float32)


def _unit_rows(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Normalised rows of [N, 3] and whether each had a usable length."""
    n = np.linalg.norm(v, axis=1, keepdims=True)
    ok = n[:, 0] > _TINY
    return np.where(ok[:, None], v / np.where(ok[:, None], n, 1.0), 0.0), ok


def normal_map(
    vertices: np.ndarray,  # [V, 3] world
    faces: np.ndarray,  # [F, 3] int, counter-clockwise seen from outside
    viewmat: np.ndarray,  # [4, 4] world->camera
    K: np.ndarray,  # [3, 3] pixels
    width: int,
    height: int,
    background: float | Sequence[float] = 0.0,
) -> NormalMap:
    """Camera-space normal map of a world-space triangle mesh (encoding: docs/formats.md, "Triplets").

    The mesh is rasterized with :func:`~trioman.runtime.mesh_raster.rasterize_mesh` (no back-face culling,
    one sample at each pixel centre, no anti-aliasing, so ``mask`` is exactly its coverage). Area-weighted
    vertex normals are interpolated with the perspective-correct barycentrics and normalised per pixel;
    where the interpolated normal vanishes (opposite normals of a two-sided sheet) the visible face's own
    normal is used instead. Pixels the mesh does not cover hold ``background``."""
    bg = _background(background)
    frags = rasterize_mesh(vertices, faces, viewmat, K, width, height)
    mask = frags.face_id >= 0
    rgb = np.empty((height, width, 3), np.float32)
    rgb[:] = bg
    if not mask.any():
        return NormalMap(rgb, mask)
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces)
    to_cam = CV_TO_NORMAL_MAP @ np.asarray(viewmat, dtype=np.float64)[:3, :3]
    n, ok = _unit_rows(interpolate(frags, vertex_normals(vertices, faces), faces)[mask].astype(np.float64))
    if not ok.all():
        tri = vertices[faces[frags.face_id[mask][~ok]]]  # [M, 3, 3]
        n[~ok] = _unit_rows(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]))[0]
    rgb[mask] = (0.5 * (_unit_rows(n @ to_cam.T)[0] + 1.0)).astype(np.float32)
    return NormalMap(rgb, mask)


def body_normal_map(
    mesh: SkinnedMesh,
    pose: np.ndarray,  # [J, 3] axis-angle
    trans: np.ndarray,  # [3]
    viewmat: np.ndarray,  # [4, 4] world->camera
    K: np.ndarray,  # [3, 3] pixels
    width: int,
    height: int,
    background: float | Sequence[float] = 0.0,
) -> NormalMap:
    """Normal map of the body posed by LBS (``SkinnedMesh.pose``) for one frame's camera."""
    pose = np.asarray(pose, dtype=np.float64)
    if pose.ndim != 2:
        raise ValueError(f"pose: expected one frame [{mesh.skeleton.num_joints}, 3], got {list(pose.shape)}")
    return normal_map(mesh.pose(pose, trans), mesh.faces, viewmat, K, width, height, background)
