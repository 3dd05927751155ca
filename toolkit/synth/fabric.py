"""Fabric, hair and shoe colours of the realistic style: solid patterns of the canonical (rest) position.

A ``Look`` (drawn from the seed) fixes every colour and pattern; ``albedo`` evaluates it at points of a
piece's rest surface, per pixel, so the same surface point has the same colour in every frame. Noise is a
hashed lattice (value noise), a function of position alone: no random state per frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from trioman.toolkit.synth.texture import CLOTH, HAIR_COLOURS, decal, planar

TOP_PATTERNS = ("solid", "stripes", "check", "dots", "logo")
BOTTOM_PATTERNS = ("denim", "solid", "check")


def value_noise(p: np.ndarray, cell: float, seed: int) -> np.ndarray:
    """Smooth noise in [0, 1] at points ``p`` [N, 3]: trilinear over a hashed lattice of side ``cell`` m. -> [N]"""
    q = np.asarray(p, np.float64) / cell
    i0 = np.floor(q).astype(np.int64)
    f = q - i0
    f = f * f * (3 - 2 * f)
    out = np.zeros(len(q))
    for dx in (0, 1):
        for dy in (0, 1):
            for dz in (0, 1):
                c = i0 + np.array([dx, dy, dz])
                h = (c[:, 0] * 73856093) ^ (c[:, 1] * 19349663) ^ (c[:, 2] * 83492791) ^ (seed * 2654435761)
                h = (h ^ (h >> 13)) * 1274126177
                v = ((h ^ (h >> 16)) & 0xFFFF) / 65535.0
                w = (f[:, 0] if dx else 1 - f[:, 0]) * (f[:, 1] if dy else 1 - f[:, 1]) * (f[:, 2] if dz else 1 - f[:, 2])
                out += w * v
    return out


@dataclass(frozen=True)
class Look:
    """Colours and patterns of one subject's outfit."""

    seed: int
    top: np.ndarray  # [3]
    top_second: np.ndarray  # [3] stripes, checks, dots
    top_pattern: str
    bottom: np.ndarray
    bottom_pattern: str
    coat: np.ndarray
    hair: np.ndarray
    shoes: np.ndarray
    sole: np.ndarray
    mark: str

    @classmethod
    def from_seed(cls, seed: int) -> "Look":
        rng = np.random.default_rng([seed, 8])
        a, b, c, d = rng.choice(len(CLOTH), size=4, replace=False)
        bottom_pattern = str(rng.choice(BOTTOM_PATTERNS))
        bottom = np.array([0.16, 0.24, 0.42]) * rng.uniform(0.8, 1.2) if bottom_pattern == "denim" else 0.65 * CLOTH[c]
        dark = rng.random() < 0.5
        return cls(
            seed=seed, top=CLOTH[a], top_second=CLOTH[b], top_pattern=str(rng.choice(TOP_PATTERNS)),
            bottom=np.clip(bottom, 0, 1), bottom_pattern=bottom_pattern, coat=0.55 * CLOTH[d] + 0.05,
            hair=HAIR_COLOURS[rng.integers(len(HAIR_COLOURS))], shoes=np.array([0.1, 0.1, 0.12]) if dark else np.array([0.9, 0.9, 0.88]),
            sole=np.array([0.85, 0.85, 0.82]) if dark else np.array([0.25, 0.22, 0.2]), mark=str(rng.integers(10, 100)),
        )


_LOGO_CACHE: dict[str, np.ndarray] = {}


def _logo(text: str) -> np.ndarray:
    if text not in _LOGO_CACHE:
        _LOGO_CACHE[text] = cv2.GaussianBlur(decal(text, 256), (3, 3), 0)
    return _LOGO_CACHE[text]


def albedo(material: str, p: np.ndarray, look: Look, chest_z: float, sole_z: float) -> np.ndarray:
    """Colour of ``material`` at rest positions ``p`` [N, 3] (world, the body faces -y); ``chest_z`` places the
    logo, ``sole_z`` tops the shoes' soles. -> [N, 3] in [0, 1]"""
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    grain = 0.92 + 0.16 * value_noise(p, 0.004, look.seed)  # weave / fibre
    blotch = 0.94 + 0.12 * value_noise(p, 0.05, look.seed + 1)  # wrinkles and wear
    if material == "top":
        second = look.top_second[None]
        base = np.repeat(look.top[None], len(p), 0)
        if look.top_pattern == "stripes":
            base = np.where((np.sin(2 * np.pi * z / 0.05) > 0.3)[:, None], second, base)
        elif look.top_pattern == "check":
            u = np.floor((x + 0.6 * y) / 0.04) + np.floor(z / 0.04)
            base = np.where((u % 2 == 1)[:, None], 0.5 * (base + second), base)
        elif look.top_pattern == "dots":
            cell = np.stack([x + 0.5 * y, z], 1) / 0.035
            d = np.linalg.norm(cell - np.round(cell), axis=1)
            base = np.where((d < 0.22)[:, None], second, base)
        elif look.top_pattern == "logo":
            mark = planar(_logo(look.mark), (x + 0.09) / 0.18, (chest_z + 0.03 - z) / 0.18) * (y < -0.02)
            base = base * (1 - mark[:, None]) + second * mark[:, None]
        out = base * (grain * blotch)[:, None]
    elif material == "bottom":
        base = np.repeat(look.bottom[None], len(p), 0)
        if look.bottom_pattern == "denim":
            twill = 0.85 + 0.3 * (np.sin(2 * np.pi * (z + 0.5 * x + 0.5 * y) / 0.003) > 0)
            fade = 1.0 + 0.35 * value_noise(p, 0.08, look.seed + 2) ** 3
            base = base * (twill * fade)[:, None]
        elif look.bottom_pattern == "check":
            u = ((x + 0.7 * y) / 0.05) % 1
            v = (z / 0.05) % 1
            lines = (np.abs(u - 0.5) < 0.05) | (np.abs(v - 0.5) < 0.05)
            base = np.where(lines[:, None], np.array([0.85, 0.8, 0.35]), base)
        out = base * (grain * blotch)[:, None]
    elif material == "coat":
        seam = np.abs(x) < 0.006
        buttons = (np.abs(x - 0.012) < 0.008) & (np.abs(((z - chest_z) / 0.09) % 1 - 0.5) < 0.06) & (y < 0)
        out = np.repeat(look.coat[None], len(p), 0) * (grain * blotch)[:, None]
        out = np.where(seam[:, None], 0.6 * out, out)
        out = np.where(buttons[:, None], np.array([0.15, 0.12, 0.1]), out)
    elif material == "hair":
        strands = 0.75 + 0.35 * value_noise(p * np.array([8.0, 8.0, 0.5]), 0.01, look.seed + 3)
        sheen = 1.0 + 0.25 * value_noise(p, 0.03, look.seed + 4)
        out = look.hair[None] * (strands * sheen)[:, None] + 0.02
    elif material == "shoes":
        low = z < sole_z
        out = np.where(low[:, None], look.sole[None], look.shoes[None]) * grain[:, None]
    else:
        raise ValueError(f"material: unknown material {material!r}")
    return np.clip(out, 0.0, 1.0)
