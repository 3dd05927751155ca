"""Procedural clothing texture baked into the body's UV atlas.

Every texel gets a garment label (skin, hair, top, trousers, shoes, eyes) from the skinning of the
triangle it lies on, and a colour from a solid (3D) pattern evaluated at the texel's canonical
position, so patterns run continuously across UV seams: striped top with a printed chest mark and a
back number, checked trousers, shoes with soles and laces, stitched seams at garment boundaries,
hair strands and fine fabric weave. Baking uses the runtime mesh rasterizer in UV space.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from trioman.runtime.mesh_raster import interpolate, rasterize_screen
from trioman.runtime.skeleton import SkinnedMesh

SKIN, HAIR, TOP, TROUSERS, SHOES, EYES = range(6)
LABEL_NAMES = ("skin", "hair", "top", "trousers", "shoes", "eyes")

_SKIN_TONES = np.array([[0.93, 0.76, 0.64], [0.84, 0.64, 0.49], [0.70, 0.51, 0.37], [0.52, 0.36, 0.25], [0.36, 0.24, 0.17]])
HAIR_COLOURS = np.array([[0.10, 0.07, 0.05], [0.28, 0.17, 0.09], [0.55, 0.38, 0.20], [0.80, 0.66, 0.42], [0.18, 0.18, 0.20]])
CLOTH = np.array(
    [[0.75, 0.12, 0.12], [0.12, 0.32, 0.70], [0.10, 0.50, 0.28], [0.90, 0.72, 0.15], [0.45, 0.18, 0.55],
     [0.92, 0.45, 0.10], [0.10, 0.55, 0.60], [0.85, 0.85, 0.82], [0.20, 0.22, 0.28], [0.60, 0.45, 0.30]]
)


@dataclass(frozen=True)
class Palette:
    skin: np.ndarray
    hair: np.ndarray
    top: np.ndarray
    top_stripe: np.ndarray
    trousers: np.ndarray
    trousers_check: np.ndarray
    shoes: np.ndarray
    mark: str

    @classmethod
    def from_seed(cls, rng: np.random.Generator) -> "Palette":
        top, stripe, trousers, check = rng.choice(len(CLOTH), size=4, replace=False)
        shoes = np.array([0.12, 0.12, 0.14]) if rng.random() < 0.5 else np.array([0.88, 0.88, 0.86])
        return cls(
            skin=_SKIN_TONES[rng.integers(len(_SKIN_TONES))],
            hair=HAIR_COLOURS[rng.integers(len(HAIR_COLOURS))],
            top=CLOTH[top],
            top_stripe=CLOTH[stripe],
            trousers=0.6 * CLOTH[trousers],
            trousers_check=0.6 * CLOTH[check] + 0.2,
            shoes=shoes,
            mark=str(rng.integers(10, 100)),
        )


def _starts(names: np.ndarray, prefixes: str | tuple[str, ...]) -> np.ndarray:
    return np.array([str(n).startswith(prefixes) for n in names])


def vertex_labels(mesh: SkinnedMesh) -> np.ndarray:
    """Garment label per vertex from its dominant joint and height. -> [V] int."""
    sk = mesh.skeleton
    dominant = np.asarray(sk.joint_names)[np.argmax(mesh.dense_weights(), axis=1)]
    z = mesh.vertices[:, 2]
    waist = sk.joints[sk.index("spine04"), 2] + 0.03
    labels = np.full(mesh.num_vertices, SKIN)
    torso = _starts(dominant, ("spine", "clavicle", "shoulder", "upperarm", "lowerarm01", "root"))
    legs = _starts(dominant, ("pelvis", "upperleg", "lowerleg"))
    labels[torso] = TOP
    labels[(legs | torso) & (z < waist) & ~_starts(dominant, ("upperarm", "lowerarm"))] = TROUSERS
    labels[_starts(dominant, ("foot", "toe"))] = SHOES
    labels[_starts(dominant, "eye")] = EYES
    # Hair: the head's crown and back (the face looks along -y).
    head = sk.joints[sk.index("head")]
    rel = mesh.vertices - head
    is_head = dominant == "head"
    labels[is_head & ((rel[:, 2] > 0.075) | ((rel[:, 2] > -0.03) & (rel[:, 1] > 0.03)))] = HAIR
    return labels


def _face_labels(labels: np.ndarray, faces: np.ndarray) -> np.ndarray:
    a, b, c = labels[faces[:, 0]], labels[faces[:, 1]], labels[faces[:, 2]]
    return np.where(b == c, b, a)


def decal(text: str, size: int = 128) -> np.ndarray:
    """A printed mark: ring, star and text, white on transparent. -> [size, size] coverage in [0, 1]."""
    img = np.zeros((size, size), np.uint8)
    cv2.circle(img, (size // 2, size // 2), size // 2 - 4, 255, 5, cv2.LINE_AA)
    pts = np.array([[size / 2 + (0.42 if k % 2 == 0 else 0.18) * size * np.sin(k * np.pi / 5),
                     size / 2 - (0.42 if k % 2 == 0 else 0.18) * size * np.cos(k * np.pi / 5)] for k in range(10)])
    cv2.polylines(img, [pts.astype(np.int32)], True, 255, 2, cv2.LINE_AA)
    cv2.putText(img, text, (size // 2 - 22, size // 2 + 12), cv2.FONT_HERSHEY_SIMPLEX, 1.0, 255, 3, cv2.LINE_AA)
    return img.astype(np.float32) / 255.0


def planar(decal: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Sample a decal at normalised coordinates u, v in [0, 1] (outside: 0)."""
    s = decal.shape[0]
    inside = (u >= 0) & (u < 1) & (v >= 0) & (v < 1)
    i = np.clip((v * s).astype(int), 0, s - 1)
    j = np.clip((u * s).astype(int), 0, s - 1)
    return np.where(inside, decal[i, j], 0.0)


def _pattern(label: np.ndarray, p: np.ndarray, mesh: SkinnedMesh, pal: Palette, rng: np.random.Generator) -> np.ndarray:
    """Colour per texel. label: [N], p: [N, 3] canonical positions -> [N, 3]."""
    sk = mesh.skeleton
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    col = np.zeros((len(p), 3))
    weave = 1.0 + 0.05 * np.sin(2 * np.pi * x / 0.004) * np.sin(2 * np.pi * z / 0.004)
    noise = 1.0 + 0.04 * rng.standard_normal(len(p))

    m = label == SKIN
    col[m] = pal.skin * (1.0 + 0.012 * np.sin(2 * np.pi * z[m] / 0.011) + 0.02 * rng.standard_normal(int(m.sum())))[:, None]
    m = label == HAIR
    strands = 0.8 + 0.2 * np.sin(2 * np.pi * (x[m] * 0.6 + y[m] * 0.4) / 0.003) ** 2
    col[m] = pal.hair * strands[:, None] + 0.05
    m = label == EYES
    eye_c = np.where(x[m, None] > 0, sk.joints[sk.index("eye.L")], sk.joints[sk.index("eye.R")])
    d = p[m] - eye_c
    front = -d[:, 1] / np.maximum(np.linalg.norm(d, axis=1), 1e-9)
    col[m] = np.where(front[:, None] > 0.93, [0.05, 0.05, 0.05], np.where(front[:, None] > 0.8, [0.25, 0.45, 0.30], [0.92, 0.92, 0.90]))

    m = label == TOP
    stripe = np.sin(2 * np.pi * z[m] / 0.06) > 0.35
    pin = np.abs(np.sin(2 * np.pi * z[m] / 0.012)) > 0.97
    top = np.where(stripe[:, None], pal.top_stripe, pal.top)
    top = np.where(pin[:, None], 0.5 * top, top)
    chest_z = sk.joints[sk.index("spine01"), 2]
    mark_front = decal(pal.mark)
    front = planar(mark_front, (x[m] + 0.075) / 0.15, (chest_z + 0.02 - z[m]) / 0.15) * (y[m] < -0.02)
    back = planar(decal(pal.mark[::-1]), (-x[m] + 0.09) / 0.18, (chest_z - z[m]) / 0.18) * (y[m] > 0.04)
    mark = np.maximum(front, back)[:, None]
    col[m] = (top * (1 - mark) + np.array([0.97, 0.97, 0.95]) * mark) * (weave[m] * noise[m])[:, None]

    m = label == TROUSERS
    u = x[m] + 0.7 * y[m]
    check = ((np.floor(u / 0.045) + np.floor(z[m] / 0.045)) % 2).astype(bool)
    lines = (np.abs(((u / 0.045) % 1) - 0.5) < 0.04) | (np.abs(((z[m] / 0.045) % 1) - 0.5) < 0.04)
    tr = np.where(check[:, None], pal.trousers_check, pal.trousers)
    tr = np.where(lines[:, None], np.array([0.9, 0.85, 0.3]), tr)
    col[m] = tr * (weave[m] * noise[m])[:, None]

    m = label == SHOES
    foot_low = min(sk.joints[sk.index("foot.L"), 2], sk.joints[sk.index("foot.R"), 2]) - 0.05
    sole = z[m] < foot_low + 0.045
    laces = (np.sin(2 * np.pi * y[m] / 0.016) > 0.6) & (z[m] > foot_low + 0.07) & (np.abs(np.abs(x[m]) - 0.18) < 0.02)
    shoe = np.where(sole[:, None], 1.0 - 0.8 * pal.shoes, pal.shoes)  # contrasting sole
    col[m] = np.where(laces[:, None], pal.top_stripe, shoe) * noise[m, None]
    return np.clip(col, 0.0, 1.0)


def bake_texture(mesh: SkinnedMesh, seed: int, size: int = 1024, garments: bool = True) -> np.ndarray:
    """The subject's texture atlas; ``garments=False``: skin and eyes only (the realistic style's garments and
    hair are meshes of their own). -> [size, size, 3] float32 in [0, 1] (row 0 is v = 1)."""
    if mesh.uvs is None:
        raise ValueError("uvs: the body mesh has no texture coordinates to bake a texture into")
    rng = np.random.default_rng(seed)
    palette = Palette.from_seed(rng)
    xy = np.stack([mesh.uvs[:, 0] * size, (1.0 - mesh.uvs[:, 1]) * size], axis=1)
    frags = rasterize_screen(xy, np.ones(len(xy)), mesh.uv_faces, size, size, perspective=False)
    covered = frags.face_id >= 0
    labels = np.full((size, size), -1)
    vertex_label = vertex_labels(mesh)
    if not garments:
        vertex_label = np.where(vertex_label == EYES, EYES, SKIN)
    labels[covered] = _face_labels(vertex_label, mesh.faces)[frags.face_id[covered]]
    pos = interpolate(frags, mesh.vertices, mesh.faces)
    tex = np.zeros((size, size, 3))
    tex[covered] = _pattern(labels[covered], pos[covered].astype(np.float64), mesh, palette, rng)
    # Seams: dark stitching where the garment label changes between neighbouring texels.
    lab = labels.astype(np.float32)
    edge = (cv2.dilate(lab, np.ones((3, 3))) != cv2.erode(lab, np.ones((3, 3)))) & covered
    seam = edge & (cv2.dilate(lab, np.ones((3, 3))) >= 0) & (cv2.erode(lab, np.ones((3, 3))) >= 0)
    tex[seam] *= 0.45
    return _dilate_into_empty(tex.astype(np.float32), covered)


def _dilate_into_empty(tex: np.ndarray, covered: np.ndarray, iterations: int = 6) -> np.ndarray:
    """Fill texels next to the UV charts with the mean of their covered neighbours (no seam bleed)."""
    tex = tex.copy()
    filled = covered.astype(np.float32)
    for _ in range(iterations):
        num = cv2.blur(tex * filled[..., None], (3, 3))
        den = cv2.blur(filled, (3, 3))
        grow = (den > 0) & (filled == 0)
        tex[grow] = num[grow] / den[grow, None]
        filled[grow] = 1.0
    return tex
