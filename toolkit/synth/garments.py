"""Hair, garments and shoes as skinned meshes of their own, dressed over a body (the realistic style).

Every piece is a triangle mesh in the body's rest pose, skinned to the body's skeleton, so one LBS poses
the body and its clothes together:

- shells: a region of the body (chosen by dominant joint and height) offset along the rest normals by a
  per-vertex thickness (a loose top hangs further from the belly towards its hem, wide trousers flare
  towards the ankle), skinned like the skin under it;
- tubes: skirts, a dress's and a coat's hem, long hair: rings around a vertical axis whose radius at each
  angle is the body's cross-section support there plus a clearance (monotone, so cloth falls), skinned
  with the distance-weighted mean of the nearest body vertices' weights;
- a bun: an ellipsoid fixed to the head.

Their colours are solid patterns of the canonical (rest) position (``toolkit/synth/fabric.py``), evaluated
per pixel, so stripes and prints run on across the pieces' edges and never swim over a moving surface.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from trioman.runtime.mesh_raster import vertex_normals
from trioman.runtime.skeleton import SkinnedMesh

TOPS = ("tshirt", "longsleeve", "tank")
BOTTOMS = ("jeans", "wide_trousers", "shorts", "skirt", "dress")
HAIRSTYLES = ("short", "bob", "long", "bun")
OUTERWEAR = ("none", "coat")

_ARMS = ("upperarm", "lowerarm", "wrist", "finger", "metacarpal")


@dataclass(frozen=True)
class Outfit:
    """What a realistic subject wears (names from TOPS, BOTTOMS, HAIRSTYLES, OUTERWEAR)."""

    top: str = "tshirt"
    bottom: str = "jeans"
    hair: str = "short"
    outer: str = "none"

    def __post_init__(self) -> None:
        for field, value, names in (("top", self.top, TOPS), ("bottom", self.bottom, BOTTOMS),
                                    ("hair", self.hair, HAIRSTYLES), ("outer", self.outer, OUTERWEAR)):
            if value not in names:
                raise ValueError(f"{field}: unknown {field} {value!r}; one of {', '.join(names)}")

    @classmethod
    def from_seed(cls, seed: int) -> "Outfit":
        rng = np.random.default_rng([seed, 7])
        bottom = str(rng.choice(BOTTOMS, p=[0.3, 0.2, 0.1, 0.2, 0.2]))
        top = "tank" if bottom == "dress" and rng.random() < 0.5 else str(rng.choice(TOPS, p=[0.45, 0.4, 0.15]))
        outer = "coat" if bottom != "dress" and rng.random() < 0.2 else "none"
        return cls(top=top, bottom=bottom, hair=str(rng.choice(HAIRSTYLES)), outer=outer)


@dataclass(frozen=True, eq=False)
class Piece:
    """One garment or hair mesh. ``material`` names its look in ``fabric.MATERIALS``'s sense."""

    name: str
    vertices: np.ndarray  # [V, 3] rest positions (m)
    faces: np.ndarray  # [F, 3] int
    weights: np.ndarray  # [V, J] dense skinning weights, rows sum to 1
    material: str


@dataclass(frozen=True, eq=False)
class DressedBody:
    """The body and its pieces as one skinned mesh; faces [0, body_faces) are the body's (with its UVs)."""

    mesh: SkinnedMesh  # body + pieces, no UVs, the body's skeleton
    body_faces: int
    face_piece: np.ndarray  # [F] int: -1 body, else the index into ``pieces``
    pieces: tuple[Piece, ...]


class _Body:
    """Rest-pose facts about a body that every piece needs."""

    def __init__(self, mesh: SkinnedMesh):
        sk = mesh.skeleton
        self.mesh, self.sk = mesh, sk
        self.v = mesh.vertices
        self.n = vertex_normals(mesh.vertices, mesh.faces)
        self.W = mesh.dense_weights()
        self.dominant = np.asarray(sk.joint_names)[np.argmax(self.W, axis=1)]
        self.z = self.v[:, 2]
        j = sk.joints
        self.waist = j[sk.index("spine04"), 2] + 0.03
        self.chest = j[sk.index("spine01"), 2]
        self.neck = j[sk.index("neck01"), 2]
        self.head = j[sk.index("head")]
        self.hip = 0.5 * (j[sk.index("upperleg01.L")] + j[sk.index("upperleg01.R")])
        self.knee = 0.5 * (j[sk.index("lowerleg01.L"), 2] + j[sk.index("lowerleg01.R"), 2])
        self.ankle = 0.5 * (j[sk.index("foot.L"), 2] + j[sk.index("foot.R"), 2])
        self.sole = float(self.z.min())
        self.arms = self.starts(_ARMS)

    def starts(self, prefixes: tuple[str, ...] | str) -> np.ndarray:
        return np.char.startswith(self.dominant.astype(str), prefixes) if isinstance(prefixes, str) else \
            np.any([np.char.startswith(self.dominant.astype(str), p) for p in prefixes], axis=0)


def _shell(body: _Body, name: str, keep: np.ndarray, offset: np.ndarray, material: str) -> Piece:
    """The faces whose three corners are all in ``keep`` [V], moved out by ``offset`` [V] metres."""
    faces = body.mesh.faces[np.all(keep[body.mesh.faces], axis=1)]
    used = np.unique(faces)
    remap = np.full(len(body.v), -1)
    remap[used] = np.arange(len(used))
    verts = body.v[used] + offset[used, None] * body.n[used]
    return Piece(name, verts, remap[faces], body.W[used], material)


def _support(body: _Body, center: np.ndarray, z: float, angles: np.ndarray, band: float, select: np.ndarray) -> np.ndarray:
    """The body's cross-section extent at height ``z`` along each direction of ``angles`` [A] (about the
    vertical axis through ``center`` [3]), over the vertices in ``select`` [V] within ``band`` m. -> [A]"""
    pick = select & (np.abs(body.z - z) < band)
    if not pick.any():
        return np.zeros(len(angles))
    rel = body.v[pick, :2] - center[:2]
    dirs = np.stack([np.sin(angles), -np.cos(angles)], axis=1)  # angle 0 = -y, the way the body faces
    return np.maximum((rel @ dirs.T).max(axis=0), 0.0)


def _knn_weights(body: _Body, points: np.ndarray, select: np.ndarray, k: int = 8) -> np.ndarray:
    """Distance-weighted mean of the skinning weights of the ``k`` nearest selected body vertices. -> [P, J]"""
    idx = np.flatnonzero(select)
    d2 = ((points[:, None, :] - body.v[None, idx, :]) ** 2).sum(-1)  # [P, S]
    near = np.argpartition(d2, k, axis=1)[:, :k]
    w = 1.0 / (np.sqrt(np.take_along_axis(d2, near, 1)) + 0.01)
    w /= w.sum(axis=1, keepdims=True)
    return np.einsum("pk,pkj->pj", w, body.W[idx[near]])


def _tube(body: _Body, name: str, center: np.ndarray, z_top: float, z_bottom: float, span: np.ndarray,
          clearance: float, flare: float, select: np.ndarray, material: str, rows: int = 24, cols: int = 72) -> Piece:
    """A skirt-like surface from ``z_top`` down to ``z_bottom``; ``span`` [rows] is each row's angular half-width
    (pi: closed all round). Each ring clears the body by ``clearance`` and widens by at least ``flare`` m per m
    of drop, as cloth that falls."""
    zs = np.linspace(z_top, z_bottom, rows)
    closed = bool(np.all(span >= np.pi))
    u = np.linspace(-1.0, 1.0, cols, endpoint=not closed) if not closed else np.arange(cols) / cols * 2 - 1
    verts, radius_prev = [], None
    for r, z in enumerate(zs):
        angles = np.pi + u * span[r] if not closed else np.pi * u
        reach = _support(body, center, z, angles, 0.025, select) + clearance
        if radius_prev is not None:
            reach = np.maximum(reach, radius_prev + flare * (zs[r - 1] - z))
        radius_prev = reach
        verts.append(np.stack([center[0] + reach * np.sin(angles), center[1] - reach * np.cos(angles), np.full(cols, z)], 1))
    verts = np.concatenate(verts)
    grid = np.arange(rows * cols).reshape(rows, cols)
    right = np.roll(grid, -1, axis=1) if closed else grid[:, 1:]
    left = grid if closed else grid[:, :-1]
    a, b, c, d = left[:-1], right[:-1], left[1:], right[1:]
    faces = np.concatenate([np.stack([a, c, b], -1).reshape(-1, 3), np.stack([b, c, d], -1).reshape(-1, 3)])
    return Piece(name, verts, faces, _knn_weights(body, verts, select & ~body.arms), material)


def _ellipsoid(center: np.ndarray, radii: np.ndarray, joint: int, num_joints: int, name: str, material: str,
               rows: int = 12, cols: int = 20) -> Piece:
    """A closed ellipsoid rigidly attached to ``joint``."""
    th = np.linspace(0, np.pi, rows)[1:-1]
    ph = np.arange(cols) / cols * 2 * np.pi
    ring = np.stack([np.sin(th)[:, None] * np.cos(ph), np.sin(th)[:, None] * np.sin(ph), np.repeat(np.cos(th)[:, None], cols, 1)], -1)
    verts = np.concatenate([[[0, 0, 1]], ring.reshape(-1, 3), [[0, 0, -1]]]) * radii + center
    grid = 1 + np.arange((rows - 2) * cols).reshape(rows - 2, cols)
    nxt = np.roll(grid, -1, axis=1)
    faces = [np.stack([np.zeros(cols, int), nxt[0], grid[0]], 1)]
    faces.append(np.stack([grid[:-1], nxt[:-1], grid[1:]], -1).reshape(-1, 3))
    faces.append(np.stack([nxt[:-1], nxt[1:], grid[1:]], -1).reshape(-1, 3))
    faces.append(np.stack([np.full(cols, len(verts) - 1), grid[-1], nxt[-1]], 1))
    W = np.zeros((len(verts), num_joints))
    W[:, joint] = 1.0
    return Piece(name, verts, np.concatenate(faces), W, material)


def _top(body: _Body, outfit: Outfit, coat: bool) -> list[Piece]:
    torso = body.starts(("spine", "clavicle", "shoulder", "root", "pelvis")) & (body.z > body.waist - (0.2 if coat else 0.12))
    sleeves = {"tshirt": ("upperarm",), "longsleeve": ("upperarm", "lowerarm"), "tank": ()}[outfit.top]
    if coat:
        sleeves = ("upperarm", "lowerarm")
    keep = torso | (body.starts(sleeves) if sleeves else False)
    if outfit.top == "tank" and not coat:
        keep &= ~(body.starts(("shoulder", "clavicle")) & (body.z > body.chest + 0.08))
    # loose: further from the body towards the hem, most at the belly and the back
    hang = np.clip((body.chest - body.z) / max(body.chest - body.waist, 1e-3), 0.0, 1.5)
    offset = (0.022 if coat else 0.012) + (0.03 if coat else 0.018) * hang
    offset = np.where(body.arms, 0.012 + (0.012 if coat else 0.004), offset)
    pieces = [_shell(body, "coat" if coat else "top", keep, offset, "coat" if coat else "top")]
    if coat:  # the coat's hem over the hips and thighs
        legs = ~body.arms & (body.z < body.waist)
        span = np.full(14, np.pi)
        pieces.append(_tube(body, "coat_hem", body.hip, body.waist - 0.05, body.knee + 0.12, span, 0.04, 0.08, legs, "coat", rows=14))
    return pieces


def _bottom(body: _Body, outfit: Outfit) -> list[Piece]:
    legs = body.starts(("pelvis", "upperleg", "lowerleg", "root", "spine05")) & (body.z < body.waist) & ~body.arms
    kind = outfit.bottom
    if kind in ("skirt", "dress"):
        hem = body.knee + (0.05 if kind == "skirt" else -0.12)
        top = body.waist + 0.02 if kind == "skirt" else body.waist - 0.06
        rows = 22
        span = np.full(rows, np.pi)
        pieces = [_tube(body, kind, body.hip, top, hem, span, 0.015, 0.25, legs | (body.z > body.waist - 0.1) & ~body.arms,
                        "bottom" if kind == "skirt" else "top", rows=rows)]
        if kind == "skirt":  # a waistband shell under the skirt's top edge
            band = legs & (body.z > body.waist - 0.06)
            pieces.append(_shell(body, "waistband", band, np.full(len(body.v), 0.012), "bottom"))
        return pieces
    if kind == "shorts":
        keep = legs & (body.z > body.knee + 0.12)
    else:
        keep = legs & (body.z > body.ankle + 0.04)
    drop = np.clip((body.knee - body.z) / max(body.knee - body.ankle, 1e-3), 0.0, 1.0)
    flare = {"jeans": 0.006, "wide_trousers": 0.05, "shorts": 0.01}[kind]
    offset = 0.008 + (0.012 if kind == "wide_trousers" else 0.0) + flare * drop
    return [_shell(body, "trousers", keep, offset, "bottom")]


def _hair(body: _Body, outfit: Outfit) -> list[Piece]:
    head = body.starts("head") & ~body.starts("eye")
    rel = body.v - body.head
    scalp = head & ((rel[:, 2] > 0.06) | ((rel[:, 2] > -0.04) & (rel[:, 1] > 0.02)))
    crown = np.clip(rel[:, 2] / 0.12, 0.0, 1.0)
    volume = {"short": 0.012, "bob": 0.018, "long": 0.016, "bun": 0.008}[outfit.hair]
    pieces = [_shell(body, "hair", scalp, volume * (0.6 + 0.8 * crown), "hair")]
    if outfit.hair in ("bob", "long"):
        z_top = body.head[2] + 0.05
        z_bottom = body.neck - 0.02 if outfit.hair == "bob" else body.chest - 0.02
        rows = 10 if outfit.hair == "bob" else 18
        zs = np.linspace(z_top, z_bottom, rows)
        # all round the back and sides of the head, only down the back below the neck
        span = np.where(zs > body.neck + 0.02, 0.62 * np.pi, 0.38 * np.pi)
        select = ~body.arms & ~body.starts("eye")
        pieces.append(_tube(body, "hair_fall", body.head, z_top, z_bottom, span, volume, 0.0, select, "hair", rows=rows, cols=40))
    if outfit.hair == "bun":
        top_back = body.head + np.array([0.0, 0.07, 0.1])
        pieces.append(_ellipsoid(top_back, np.array([0.05, 0.045, 0.045]), body.sk.index("head"), body.sk.num_joints,
                                 "bun", "hair"))
    return pieces


def _shoes(body: _Body) -> list[Piece]:
    feet = body.starts(("foot", "toe")) | (body.starts("lowerleg") & (body.z < body.ankle + 0.03))
    low = np.clip((body.ankle - body.z) / max(body.ankle - body.sole, 1e-3), 0.0, 1.0)
    return [_shell(body, "shoes", feet, 0.006 + 0.006 * low, "shoes")]


def dress(mesh: SkinnedMesh, outfit: Outfit) -> DressedBody:
    """The body with the outfit's pieces, as one skinned mesh (pieces keep the body's influence count)."""
    body = _Body(mesh)
    pieces = _shoes(body) + _bottom(body, outfit) + _top(body, outfit, coat=False)
    if outfit.outer == "coat":
        pieces += _top(body, outfit, coat=True)
    pieces += _hair(body, outfit)
    K = mesh.skin_indices.shape[1]
    verts, faces, idx, wts, face_piece = [mesh.vertices], [mesh.faces], [mesh.skin_indices], [mesh.skin_weights], [
        np.full(len(mesh.faces), -1)]
    base = mesh.num_vertices
    for p, piece in enumerate(pieces):
        top = np.argsort(-piece.weights, axis=1)[:, :K]
        w = np.take_along_axis(piece.weights, top, 1)
        w /= w.sum(axis=1, keepdims=True)
        verts.append(piece.vertices)
        faces.append(piece.faces + base)
        idx.append(top)
        wts.append(w)
        face_piece.append(np.full(len(piece.faces), p))
        base += len(piece.vertices)
    combined = SkinnedMesh(mesh.skeleton, np.concatenate(verts), np.concatenate(faces), np.concatenate(idx),
                           np.concatenate(wts).astype(np.float32))
    return DressedBody(combined, len(mesh.faces), np.concatenate(face_piece), tuple(pieces))
