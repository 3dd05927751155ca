"""A procedural room behind a realistic subject: floor, walls, ceiling, a window, pictures, a door and a
cabinet, drawn by the mesh rasterizer through the frame's own camera (parallax and the test views' other
walls come for free).

Surfaces are quads cut into cells of at most ``CELL`` m (the mesh rasterizer drops a triangle with a corner
behind the near plane, so only cells at the camera are lost); each quad samples its own texture, whose
texel size is ``1 / PX_PER_M`` m.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import skimage.data

from trioman.runtime.mesh_raster import rasterize_mesh, sample_texture
from trioman.toolkit.synth.fabric import value_noise

CELL = 0.5
PX_PER_M = 128
_PICTURES = ("coffee", "chelsea", "rocket", "hubble_deep_field", "immunohistochemistry")
_PAINT = np.array([[0.86, 0.83, 0.76], [0.78, 0.80, 0.78], [0.70, 0.76, 0.80], [0.82, 0.74, 0.66], [0.66, 0.70, 0.62],
                   [0.88, 0.87, 0.85]])
_WOOD = np.array([[0.55, 0.38, 0.22], [0.66, 0.50, 0.32], [0.42, 0.28, 0.18], [0.72, 0.62, 0.48]])


@dataclass(frozen=True, eq=False)
class Quad:
    origin: np.ndarray  # [3] world corner at texture (0, 0): bottom left seen from inside
    u_axis: np.ndarray  # [3] the texture's right edge (m, its length the quad's width)
    v_axis: np.ndarray  # [3] the texture's up edge
    texture: np.ndarray  # [Ht, Wt, 3] float32, row 0 at the top


@dataclass(frozen=True, eq=False)
class Room:
    vertices: np.ndarray  # [V, 3]
    faces: np.ndarray  # [F, 3]
    uvs: np.ndarray  # [V, 2] texture coordinates within the vertex's quad
    face_quad: np.ndarray  # [F] quad index
    textures: tuple[np.ndarray, ...]

    def render(self, viewmat: np.ndarray, K: np.ndarray, width: int, height: int) -> np.ndarray:
        """The room through a camera -> [H, W, 3] float32 (grey where no surface: never, inside the room)."""
        frags = rasterize_mesh(self.vertices, self.faces, viewmat, K, width, height)
        out = np.full((height, width, 3), 0.5, np.float32)
        hit = frags.face_id >= 0
        fid = frags.face_id[hit]
        uv = np.einsum("pk,pkc->pc", frags.bary[hit], self.uvs[self.faces[fid]])
        quad = self.face_quad[fid]
        rows = np.flatnonzero(hit.ravel())
        flat = out.reshape(-1, 3)
        for q in np.unique(quad):
            pick = quad == q
            flat[rows[pick]] = sample_texture(self.textures[q], uv[pick])
        return out


def _grain(shape: tuple[int, int], scale: float, seed: int, stretch: tuple[float, float] = (1.0, 1.0)) -> np.ndarray:
    """Value noise over a texture's texels. -> [H, W] in [0, 1]"""
    h, w = shape
    r, c = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
    pts = np.stack([c.ravel() * stretch[0], r.ravel() * stretch[1], np.zeros(h * w)], 1)
    return value_noise(pts, scale, seed).reshape(h, w)


def _canvas(width_m: float, height_m: float) -> tuple[int, int]:
    return max(8, int(round(height_m * PX_PER_M))), max(8, int(round(width_m * PX_PER_M)))


def _floor(w: float, d: float, rug_row: float, rng: np.random.Generator, seed: int) -> np.ndarray:
    """Planks, and a rug centred ``rug_row`` m from the texture's top (the back wall)."""
    h, wpx = _canvas(w, d)
    wood = _WOOD[rng.integers(len(_WOOD))]
    plank_w, plank_l = rng.uniform(0.12, 0.2), rng.uniform(0.9, 1.5)
    r, c = np.meshgrid(np.arange(h) / PX_PER_M, np.arange(wpx) / PX_PER_M, indexing="ij")
    row = np.floor(c / plank_w)
    offset = (row * 0.37 % 1.0) * plank_l
    col = np.floor((r + offset) / plank_l)
    tint = 0.85 + 0.3 * ((np.sin(row * 12.9898 + col * 78.233) * 43758.5453) % 1.0)
    grain = 0.85 + 0.3 * _grain((h, wpx), 3.0, seed, stretch=(6.0, 0.5))
    gap = (np.minimum(c % plank_w, plank_w - c % plank_w) < 0.003) | (np.minimum((r + offset) % plank_l, plank_l - (r + offset) % plank_l) < 0.003)
    tex = wood[None, None] * (tint * grain)[..., None]
    tex[gap] *= 0.35
    # a rug in the middle of the room
    rug = (np.abs(c - w / 2) < 1.1) & (np.abs(r - rug_row) < 1.5)
    if rng.random() < 0.7:
        colors = np.array([[0.55, 0.15, 0.15], [0.20, 0.25, 0.45], [0.75, 0.70, 0.60]])
        a, b = rng.choice(len(colors), 2, replace=False)
        pattern = (np.sin(c * 9) * np.sin(r * 9) > 0.2) | (np.minimum(1.1 - np.abs(c - w / 2), 1.5 - np.abs(r - rug_row)) < 0.12)
        rug_tex = np.where(pattern[..., None], colors[a], colors[b]) * (0.9 + 0.2 * _grain((h, wpx), 1.5, seed + 1))[..., None]
        tex[rug] = rug_tex[rug]
    return tex


def _wall(w: float, h_m: float, paint: np.ndarray, items: list[tuple[str, float, float, float, float]],
          rng: np.random.Generator, seed: int) -> np.ndarray:
    """A painted wall with a skirting board and ``items`` (kind, x, z, width, height in m from its bottom left)."""
    h, wpx = _canvas(w, h_m)
    light = 0.8 + 0.2 * np.linspace(1.0, 0.0, h)[:, None] ** 0.5  # brighter towards the ceiling
    tex = paint[None, None] * (light * (0.96 + 0.08 * _grain((h, wpx), 40.0, seed)))[..., None]
    tex[-int(0.1 * PX_PER_M):] = np.array([0.93, 0.92, 0.9])  # skirting board
    for kind, x, z, iw, ih in items:
        c0, c1 = int(x * PX_PER_M), int((x + iw) * PX_PER_M)
        r0, r1 = h - int((z + ih) * PX_PER_M), h - int(z * PX_PER_M)
        box = tex[r0:r1, c0:c1]
        bh, bw = box.shape[:2]
        if kind == "window":
            sky = np.linspace([0.85, 0.92, 1.0], [0.98, 0.98, 0.96], bh)[:, None] * np.ones((1, bw, 1))
            box[:] = sky
            t = max(2, int(0.05 * PX_PER_M))
            box[:t], box[-t:], box[:, :t], box[:, -t:] = 0.95, 0.95, 0.95, 0.95
            box[bh // 2 - t // 2: bh // 2 + t // 2] = 0.95
            box[:, bw // 2 - t // 2: bw // 2 + t // 2] = 0.95
        elif kind == "door":
            wood = _WOOD[rng.integers(len(_WOOD))] * (0.9 + 0.2 * _grain((bh, bw), 2.0, seed + 5, (0.3, 5.0)))[..., None]
            box[:] = wood
            t = max(2, int(0.04 * PX_PER_M))
            box[:t], box[:, :t], box[:, -t:] = 0.9, 0.9, 0.9
            k = (int(0.5 * bh), int(0.85 * bw))
            cv2.circle(box, (k[1], k[0]), max(2, int(0.03 * PX_PER_M)), (0.8, 0.7, 0.3), -1)
        elif kind.startswith("picture:"):
            img = getattr(skimage.data, kind.split(":", 1)[1])()
            img = img[..., :3] if img.ndim == 3 else np.repeat(img[..., None], 3, -1)
            t = max(2, int(0.04 * PX_PER_M))
            box[:] = np.array([0.12, 0.1, 0.08])
            box[t:-t, t:-t] = cv2.resize(img, (bw - 2 * t, bh - 2 * t), interpolation=cv2.INTER_AREA) / 255.0
        elif kind == "shelf":
            box[:] = 0.85 * paint
            for k in range(4):
                rr = int(k * bh / 4)
                box[rr: rr + max(2, int(0.025 * PX_PER_M))] = _WOOD[1]
                for j in range(int(bw / (0.05 * PX_PER_M))):
                    if rng.random() < 0.6:
                        cc = int(j * 0.05 * PX_PER_M)
                        top = rr + int(rng.uniform(0.05, 0.12) * PX_PER_M)
                        box[top: rr + int(bh / 4), cc: cc + int(0.04 * PX_PER_M)] = _PAINT[rng.integers(len(_PAINT))] * rng.uniform(0.3, 0.9)
    return tex.astype(np.float32)


def _quads_to_mesh(quads: list[Quad]) -> Room:
    verts, faces, uvs, face_quad = [], [], [], []
    base = 0
    for q, quad in enumerate(quads):
        nu = max(1, int(np.ceil(np.linalg.norm(quad.u_axis) / CELL)))
        nv = max(1, int(np.ceil(np.linalg.norm(quad.v_axis) / CELL)))
        s, t = np.meshgrid(np.linspace(0, 1, nu + 1), np.linspace(0, 1, nv + 1), indexing="ij")
        verts.append(quad.origin + s.ravel()[:, None] * quad.u_axis + t.ravel()[:, None] * quad.v_axis)
        uvs.append(np.stack([s.ravel(), t.ravel()], 1))
        g = base + np.arange((nu + 1) * (nv + 1)).reshape(nu + 1, nv + 1)
        a, b, c, d = g[:-1, :-1], g[1:, :-1], g[:-1, 1:], g[1:, 1:]
        f = np.concatenate([np.stack([a, b, d], -1).reshape(-1, 3), np.stack([a, d, c], -1).reshape(-1, 3)])
        faces.append(f)
        face_quad.append(np.full(len(f), q))
        base += (nu + 1) * (nv + 1)
    return Room(np.concatenate(verts), np.concatenate(faces), np.concatenate(uvs), np.concatenate(face_quad),
                tuple(q.texture.astype(np.float32) for q in quads))


def build_room(seed: int, floor_z: float, x_half: float = 4.0, y_back: float = 3.0, y_front: float = -4.0,
               height: float = 3.2) -> Room:
    """A room around the origin (the subject stands at x = y = 0 facing -y, towards ``y_front``)."""
    rng = np.random.default_rng([seed, 9])
    paint = _PAINT[rng.integers(len(_PAINT))]
    w, d = 2 * x_half, y_back - y_front
    pictures = [f"picture:{p}" for p in rng.permutation(_PICTURES)]
    z0 = floor_z
    P = np.array
    quads = [
        Quad(P([-x_half, y_front, z0]), P([w, 0, 0]), P([0, d, 0]), _floor(w, d, y_back, rng, seed)),
        Quad(P([-x_half, y_back, z0 + height]), P([w, 0, 0]), P([0, -d, 0]), np.full((16, 16, 3), 0.92, np.float32)),
        # back wall (seen behind the subject from the front), left to right seen from inside
        Quad(P([-x_half, y_back, z0]), P([w, 0, 0]), P([0, 0, height]),
             _wall(w, height, paint, [(pictures[0], 1.2, 1.3, 1.2, 0.8), ("shelf", 5.3, 0.0, 1.4, 2.0),
                                      (pictures[1], 3.4, 1.5, 0.6, 0.8)], rng, seed + 10)),
        # right wall (x = +x_half), from the back to the front
        Quad(P([x_half, y_back, z0]), P([0, -d, 0]), P([0, 0, height]),
             _wall(d, height, paint, [("window", 1.5, 0.9, 2.0, 1.5), (pictures[2], 4.4, 1.3, 0.9, 0.7)], rng, seed + 11)),
        # left wall (x = -x_half), from the front to the back
        Quad(P([-x_half, y_front, z0]), P([0, d, 0]), P([0, 0, height]),
             _wall(d, height, paint, [("door", 1.0, 0.0, 0.9, 2.1), (pictures[3], 3.2, 1.2, 1.4, 0.9)], rng, seed + 12)),
        # front wall (behind the training camera)
        Quad(P([x_half, y_front, z0]), P([-w, 0, 0]), P([0, 0, height]),
             _wall(w, height, paint, [("window", 2.5, 0.9, 1.6, 1.4), (pictures[4], 5.5, 1.3, 0.8, 0.6)], rng, seed + 13)),
    ]
    # a cabinet against the back wall: front, top and sides
    cab = _WOOD[rng.integers(len(_WOOD))]
    cx, cw, cd, ch = -x_half + 0.4, 1.2, 0.45, 0.85
    wood = lambda a, b: (cab[None, None] * (0.85 + 0.3 * _grain(_canvas(a, b), 3.0, seed + 20, (0.4, 4.0)))[..., None])  # noqa: E731
    front = wood(cw, ch)
    front[:, front.shape[1] // 2 - 1: front.shape[1] // 2 + 1] *= 0.4
    quads += [
        Quad(P([cx, y_back - cd, z0]), P([cw, 0, 0]), P([0, 0, ch]), front),
        Quad(P([cx, y_back - cd, z0 + ch]), P([cw, 0, 0]), P([0, cd, 0]), wood(cw, cd) * 1.1),
        Quad(P([cx + cw, y_back - cd, z0]), P([0, cd, 0]), P([0, 0, ch]), wood(cd, ch) * 0.8),
        Quad(P([cx, y_back, z0]), P([0, -cd, 0]), P([0, 0, ch]), wood(cd, ch) * 0.8),
    ]
    return _quads_to_mesh([Quad(q.origin, q.u_axis, q.v_axis, np.clip(q.texture, 0, 1)) for q in quads])
