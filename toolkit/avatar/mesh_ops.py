"""Mesh helpers for the avatar: midpoint subdivision with skinning transfer, neighbour graphs."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from trioman.runtime.skeleton import SkinnedMesh


def subdivide(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One midpoint subdivision (each triangle -> 4).

    -> vertices [V', 3], faces [4F, 3], source [V'] (the original vertex each new vertex takes its
    skinning from: itself for original vertices, the nearer edge end, ties to the lower index).
    """
    V = len(vertices)
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    uniq, inverse = np.unique(edges, axis=0, return_inverse=True)
    mids = 0.5 * (vertices[uniq[:, 0]] + vertices[uniq[:, 1]])
    F = len(faces)
    m01, m12, m20 = (V + inverse[k * F : (k + 1) * F] for k in range(3))
    a, b, c = faces[:, 0], faces[:, 1], faces[:, 2]
    new_faces = np.concatenate([np.stack(t, 1) for t in ((a, m01, m20), (b, m12, m01), (c, m20, m12), (m01, m12, m20))])
    source = np.concatenate([np.arange(V), uniq[:, 0]])  # the midpoint is equidistant: lower index
    return np.concatenate([vertices, mids]), new_faces.astype(np.int32), source


def knn(points: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """The k nearest other points. -> indices [N, k] int64, distances [N, k]."""
    k = min(k, len(points) - 1)
    dist, idx = cKDTree(points).query(points, k=k + 1)
    return idx[:, 1:].astype(np.int64), dist[:, 1:]


def avatar_points(mesh: SkinnedMesh, subdivisions: int = 0, keep: float = 1.0, seed: int = 0):
    """Canonical Gaussian centres and their skinning. -> points [N, 3], skin_indices [N, K], skin_weights [N, K].

    ``subdivisions`` midpoint steps add vertices (skinned like their source vertex); ``keep`` < 1
    keeps a seeded random subset for speed.
    """
    if not 0.0 < keep <= 1.0:
        raise ValueError(f"keep: must lie in (0, 1], got {keep}")
    if subdivisions < 0:
        raise ValueError(f"subdivisions: must be >= 0, got {subdivisions}")
    verts, faces, source = mesh.vertices, mesh.faces, np.arange(mesh.num_vertices)
    for _ in range(subdivisions):
        verts, faces, step_source = subdivide(verts, faces)
        source = source[step_source]
    if keep < 1.0:
        rng = np.random.default_rng(seed)
        chosen = np.sort(rng.choice(len(verts), size=max(1, int(round(keep * len(verts)))), replace=False))
        verts, source = verts[chosen], source[chosen]
    return verts, mesh.skin_indices[source], mesh.skin_weights[source]
