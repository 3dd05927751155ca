"""A colour field painted on a skinned box and its brute-force rendering: the scene the geometry-aligned
reference (tests/runtime/test_aligned.py) and the tests built on it share."""

import numpy as np
import trimesh

from trioman.runtime.aligned import SourceViews
from trioman.runtime.cameras import intrinsics, orbit_viewmat
from trioman.runtime.mesh_raster import interpolate, rasterize_mesh
from trioman.runtime.skeleton import Skeleton, SkinnedMesh

SIZE = 64
K = intrinsics(90.0, 90.0, SIZE / 2, SIZE / 2)
CENTER = np.array([0.0, 0.0, 0.5])


def _box() -> SkinnedMesh:
    box = trimesh.creation.box(extents=(0.4, 0.3, 1.0)).subdivide().subdivide().subdivide()
    V = np.asarray(box.vertices) + [0.0, 0.0, 0.5]
    sk = Skeleton(("root", "spine01"), np.array([-1, 0]), np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.5]]))
    w = np.stack([1.0 - V[:, 2], V[:, 2]], axis=1).astype(np.float32)
    return SkinnedMesh(sk, V, np.asarray(box.faces), np.tile([0, 1], (len(V), 1)), w)


MESH = _box()
_CHECKS = 0.25 * np.sign(np.sin(40 * MESH.vertices[:, 0]) * np.sin(40 * MESH.vertices[:, 1]) * np.sin(25 * MESH.vertices[:, 2]))
COLOURS = np.clip(0.5 + np.stack([MESH.vertices[:, 0], MESH.vertices[:, 1] * 1.5, MESH.vertices[:, 2] - 0.5], 1)
                  + _CHECKS[:, None], 0, 1)  # a gradient with checks: texture for the optical flow
POSE = np.zeros((2, 3))
TRANS = np.zeros(3)


def paint(pose, trans, viewmat):
    """Brute force: the colour field on the posed box seen by a camera -> (rgb [H, W, 3] on black, mask [H, W])."""
    frags = rasterize_mesh(MESH.pose(pose, trans), MESH.faces, viewmat, K, SIZE, SIZE)
    mask = (frags.face_id >= 0).astype(np.float32)
    return interpolate(frags, COLOURS, MESH.faces) * mask[..., None], mask


def views(cameras, masks=None):
    frames = [paint(POSE, TRANS, v) for v in cameras]
    masks = [m for _, m in frames] if masks is None else masks
    return SourceViews(lambda p: frames[p][0] * masks[p][..., None], lambda p: masks[p], np.stack([POSE] * len(cameras)),
                       np.zeros((len(cameras), 3)), np.stack(cameras), np.stack([K] * len(cameras)), SIZE, SIZE)


FRONT = orbit_viewmat(CENTER, 0.0, 0.1, 3.0)
