"""Mesh helpers for the avatar: midpoint subdivision with skinning transfer and level interpolation, neighbour graphs."""

from __future__ import annotations

import numpy as np
from scipy import sparse
from scipy.spatial import cKDTree

from trioman.runtime.skeleton import SkinnedMesh


def subdivide(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One midpoint subdivision (each triangle -> 4).

    -> vertices [V', 3], faces [4F, 3], source [V'] (the original vertex each new vertex takes its
    skinning from: itself for original vertices, the nearer edge end, ties to the lower index).
    """
    V = len(vertices)
    uniq, inverse = _edges(faces)
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
    _check_levels(subdivisions, keep)
    verts, faces, source = mesh.vertices, mesh.faces, np.arange(mesh.num_vertices)
    for _ in range(subdivisions):
        verts, faces, step_source = subdivide(verts, faces)
        source = source[step_source]
    chosen = _kept(len(verts), keep, seed)
    return verts[chosen], mesh.skin_indices[source[chosen]], mesh.skin_weights[source[chosen]]


def level_interpolation(mesh: SkinnedMesh, level: int, subdivisions: int = 0, keep: float = 1.0,
                        seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The avatar's points (``avatar_points`` with the same arguments) as averages of the vertices of the mesh
    after ``level`` <= ``subdivisions`` midpoint steps, exactly as the subdivision makes them (a midpoint is the
    mean of its edge's two ends, level by level).

    -> points [M, 3] (the level's vertices), indices [N, P] int64, weights [N, P] float32: avatar point n is
    ``sum_p weights[n, p] points[indices[n, p]]``; each row's columns ascend, then zero-weight padding at
    column 0; P = the most parents of a point (1 at ``level == subdivisions``, at most 2 per extra step).
    """
    _check_levels(subdivisions, keep)
    if not 0 <= level <= subdivisions:
        raise ValueError(f"level: must lie in [0, subdivisions = {subdivisions}], got {level}")
    verts, faces = mesh.vertices, mesh.faces
    for _ in range(level):
        verts, faces, _ = subdivide(verts, faces)
    points = verts
    rows = sparse.identity(len(verts), format="csr")  # level vertices -> themselves
    for _ in range(subdivisions - level):
        ends = _edges(faces)[0]
        verts, faces, _ = subdivide(verts, faces)
        rows = sparse.vstack([rows, 0.5 * (rows[ends[:, 0]] + rows[ends[:, 1]])], format="csr")
    rows = rows[_kept(len(verts), keep, seed)]
    rows.sum_duplicates()
    rows.sort_indices()
    return points, *_padded(rows)


def _edges(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """faces [F, 3] -> the unique edges [E, 2] (ends ascending; in the order ``subdivide`` appends their
    midpoints) and each face side's edge [3F] (sides 01, 12, 20 of every face, side by side)."""
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    return np.unique(edges, axis=0, return_inverse=True)


def _padded(rows: sparse.csr_matrix) -> tuple[np.ndarray, np.ndarray]:
    """A CSR matrix [N, M] -> indices [N, P] int64, weights [N, P] float32 (each row's entries, then zeros at column 0)."""
    counts = np.diff(rows.indptr)
    P = int(counts.max())
    indices = np.zeros((rows.shape[0], P), np.int64)
    weights = np.zeros((rows.shape[0], P), np.float32)
    slot = np.arange(rows.nnz) - np.repeat(rows.indptr[:-1], counts)
    row = np.repeat(np.arange(rows.shape[0]), counts)
    indices[row, slot] = rows.indices
    weights[row, slot] = rows.data
    return indices, weights


def _check_levels(subdivisions: int, keep: float) -> None:
    """ValueError naming ``keep`` outside (0, 1] or ``subdivisions`` < 0."""
    if not 0.0 < keep <= 1.0:
        raise ValueError(f"keep: must lie in (0, 1], got {keep}")
    if subdivisions < 0:
        raise ValueError(f"subdivisions: must be >= 0, got {subdivisions}")


def _kept(n: int, keep: float, seed: int) -> np.ndarray:
    """The points ``keep`` keeps of ``n``: all, or a seeded random subset in ascending order. -> indices [n']."""
    if keep >= 1.0:
        return np.arange(n)
    rng = np.random.default_rng(seed)
    return np.sort(rng.choice(n, size=max(1, int(round(keep * n))), replace=False))
