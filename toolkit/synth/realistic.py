"""The realistic style's image formation: a dressed person (hair, garments, shoes) lit by a world-fixed key
light with soft self-shadowing, in a room, filmed by a hand-held phone (jitter, exposure drift, motion blur,
noise, JPEG).

Two renders come out of one ``Scene``: ``person`` is the truth of the whole person at any pose and camera
(sharp, clean, premultiplied on black, with its coverage: the ceiling's pseudo-GT), and ``frame`` is what
the phone recorded at a subject's frame (the person over the room through the sensor), from which the
subject stores ``frame * mask`` and the mask, as an importer stores a real capture.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from trioman.runtime.mesh_raster import rasterize_mesh, rasterize_screen, sample_texture, vertex_normals
from trioman.runtime.rotations import axis_angle_to_matrix
from trioman.runtime.skeleton import SkinnedMesh
from trioman.toolkit.synth.fabric import Look, albedo
from trioman.toolkit.synth.garments import DressedBody, Outfit, dress
from trioman.toolkit.synth.room import Room, build_room
from trioman.toolkit.synth.texture import bake_texture

SHADOW_TEXEL = 0.006  # m, the shadow map's texel
SHADOW_BIAS = 0.02  # m, depth a point may lie behind the first surface and still be lit


@dataclass(frozen=True)
class Light:
    """A directional key light fixed in the world plus a coloured ambient term."""

    key_dir: np.ndarray  # [3] towards the light, world, unit
    key: np.ndarray  # [3] key colour x intensity
    ambient: np.ndarray  # [3]

    @classmethod
    def from_seed(cls, seed: int) -> "Light":
        rng = np.random.default_rng([seed, 10])
        az, el = rng.uniform(-2.2, 2.2), rng.uniform(0.5, 1.1)  # from the side or the front, above
        d = np.array([np.sin(az) * np.cos(el), -np.cos(az) * np.cos(el), np.sin(el)])
        warm = rng.uniform(-1.0, 1.0)  # warm or cool key, the ambient the other way
        key = rng.uniform(0.5, 0.65) * np.array([1.0 + 0.08 * warm, 1.0, 1.0 - 0.1 * warm])
        ambient = rng.uniform(0.38, 0.48) * np.array([1.0 - 0.05 * warm, 1.0, 1.0 + 0.06 * warm])
        return cls(d / np.linalg.norm(d), key, ambient)


@dataclass(frozen=True)
class Sensor:
    """The phone: exposure drift, shot and read noise, JPEG quality, sub-frame samples of the shutter."""

    drift: float  # relative exposure swing over the clip
    shot: float  # variance per unit intensity
    read: float  # variance floor
    jpeg_quality: int
    shutter_samples: int  # renders averaged over half a frame interval (1: no motion blur)

    @classmethod
    def from_seed(cls, seed: int) -> "Sensor":
        rng = np.random.default_rng([seed, 11])
        return cls(drift=float(rng.uniform(0.01, 0.04)), shot=float(rng.uniform(2e-4, 8e-4)), read=float(rng.uniform(1e-5, 4e-5)),
                   jpeg_quality=int(rng.integers(78, 93)), shutter_samples=2)

    def gain(self, index: int, frames: int) -> float:
        """Exposure of frame ``index``: a slow swing as an auto-exposure follows the scene."""
        return 1.0 + self.drift * np.sin(2 * np.pi * index / max(frames, 1) * 1.5 + 0.7)

    def record(self, image: np.ndarray, index: int, frames: int, seed: int) -> np.ndarray:
        """The sensor's output for the light ``image`` [H, W, 3]: gain, noise, 8-bit JPEG. -> [H, W, 3] float32"""
        rng = np.random.default_rng([seed, 12, index])
        x = np.clip(image * self.gain(index, frames), 0.0, 1.0)
        x = x + rng.standard_normal(x.shape) * np.sqrt(self.shot * x + self.read)
        u8 = np.rint(np.clip(x, 0.0, 1.0) * 255.0).astype(np.uint8)
        ok, data = cv2.imencode(".jpg", u8[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, self.jpeg_quality])
        if not ok:
            raise RuntimeError("JPEG encoding failed")
        return (cv2.imdecode(data, cv2.IMREAD_COLOR)[..., ::-1] / 255.0).astype(np.float32)


def handheld(frames: int, amplitude_deg: float, seed: int) -> np.ndarray:
    """A phone's small rotations over a clip: smooth random yaw, pitch and roll. -> [N, 3, 3] camera-frame rotations"""
    if amplitude_deg == 0:
        return np.repeat(np.eye(3)[None], frames, 0)
    rng = np.random.default_rng([seed, 13])
    walk = rng.standard_normal((frames + 40, 3))
    smooth = cv2.GaussianBlur(walk, (1, 41), 8.0, borderType=cv2.BORDER_REFLECT)[20:20 + frames]
    smooth /= max(float(smooth.std()), 1e-9)
    return axis_angle_to_matrix(np.deg2rad(amplitude_deg) * smooth * np.array([1.0, 1.0, 0.5]))


def _shadow_visibility(points: np.ndarray, verts: np.ndarray, faces: np.ndarray, to_light: np.ndarray) -> np.ndarray:
    """How lit each of ``points`` [P, 3] is by a directional light (3 x 3 percentage-closer filter over an
    orthographic shadow map of the mesh). -> [P] in [0, 1]"""
    up = np.array([0.0, 0.0, 1.0]) if abs(to_light[2]) < 0.95 else np.array([1.0, 0.0, 0.0])
    u = np.cross(up, to_light)
    u /= np.linalg.norm(u)
    v = np.cross(to_light, u)
    lo = np.stack([verts @ u, verts @ v], 1).min(0) - 4 * SHADOW_TEXEL
    size = np.ceil((np.stack([verts @ u, verts @ v], 1).max(0) - lo) / SHADOW_TEXEL).astype(int) + 8

    def texel(p: np.ndarray) -> np.ndarray:
        return (np.stack([p @ u, p @ v], 1) - lo) / SHADOW_TEXEL

    far = 10.0 - verts @ to_light  # > 0, smaller is closer to the light
    frags = rasterize_screen(texel(verts), far, faces, int(size[0]), int(size[1]), perspective=False)
    depth = np.where(frags.face_id >= 0, frags.depth, np.inf)
    xy = texel(points)
    d = 10.0 - points @ to_light - SHADOW_BIAS
    lit = np.zeros(len(points))
    for dy in (-1.5, 0.0, 1.5):
        for dx in (-1.5, 0.0, 1.5):
            j = np.clip((xy[:, 0] + dx).astype(int), 0, size[0] - 1)
            i = np.clip((xy[:, 1] + dy).astype(int), 0, size[1] - 1)
            lit += d <= depth[i, j]
    return lit / 9.0


class Scene:
    """A realistic subject's person, light, room and sensor, all from its seed (and an optional outfit)."""

    def __init__(self, body: SkinnedMesh, seed: int, outfit: Outfit | None = None, texture_size: int = 1024):
        self.seed = seed
        self.outfit = outfit or Outfit.from_seed(seed)
        self.dressed: DressedBody = dress(body, self.outfit)
        self.look = Look.from_seed(seed)
        self.skin = bake_texture(body, seed=seed, size=texture_size, garments=False)
        self.light = Light.from_seed(seed)
        self.sensor = Sensor.from_seed(seed)
        sk = body.skeleton
        self.chest_z = float(sk.joints[sk.index("spine01"), 2])
        self.sole_z = float(body.vertices[:, 2].min()) + 0.02
        self.room: Room = build_room(seed, floor_z=float(body.vertices[:, 2].min()) - 0.008)
        self._materials = [p.material for p in self.dressed.pieces]
        self._uv_corners = body.uvs[body.uv_faces].astype(np.float64)  # [F_body, 3, 2]

    @property
    def mesh(self) -> SkinnedMesh:
        """The body with every piece, one skinned mesh."""
        return self.dressed.mesh

    def person(self, verts: np.ndarray, viewmat: np.ndarray, K: np.ndarray, width: int, height: int,
               supersample: int = 2) -> tuple[np.ndarray, np.ndarray]:
        """The dressed person at posed vertices ``verts`` [V, 3] (``self.mesh``'s) -> (rgb [H, W, 3] premultiplied
        on black, coverage [H, W]), ``supersample``^2 samples a pixel."""
        ss = int(supersample)
        if ss < 1:
            raise ValueError(f"supersample: must be >= 1, got {supersample}")
        d, mesh = self.dressed, self.dressed.mesh
        K_ss = np.array(K, np.float64)
        K_ss[:2] *= ss
        frags = rasterize_mesh(verts, mesh.faces, viewmat, K_ss, width * ss, height * ss)
        hit = frags.face_id >= 0
        fid = frags.face_id[hit]
        bary = frags.bary[hit].astype(np.float64)
        corners = mesh.faces[fid]  # [P, 3]
        world = np.einsum("pk,pkc->pc", bary, verts[corners])
        rest = np.einsum("pk,pkc->pc", bary, mesh.vertices[corners])
        n = np.einsum("pk,pkc->pc", bary, vertex_normals(verts, mesh.faces)[corners])
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-8)
        cam = -viewmat[:3, :3].T @ viewmat[:3, 3]
        to_cam = cam - world
        inside = np.einsum("pc,pc->p", n, to_cam) < 0  # the inside of a skirt or a sleeve
        n[inside] *= -1.0

        col = np.zeros((len(fid), 3))
        piece = d.face_piece[fid]
        on_body = piece < 0
        if on_body.any():
            body_body = fid[on_body]
            uv = np.einsum("pk,pkc->pc", bary[on_body], self._uv_corners[body_body])
            col[on_body] = sample_texture(self.skin, uv)
        for p in np.unique(piece[~on_body]):
            pick = piece == p
            col[pick] = albedo(self._materials[p], rest[pick], self.look, self.chest_z, self.sole_z)

        lit = _shadow_visibility(world, verts, mesh.faces, self.light.key_dir)
        lam = np.clip(n @ self.light.key_dir, 0.0, None) * lit
        view = np.clip(np.einsum("pc,pc->p", n, to_cam / np.linalg.norm(to_cam, axis=1, keepdims=True)), 0.0, 1.0)
        shade = self.light.ambient[None] * (0.75 + 0.25 * view)[:, None] + self.light.key[None] * lam[:, None]
        shade[inside] *= 0.55
        rgb = np.zeros((height * ss, width * ss, 3))
        rgb[hit] = np.clip(col * shade, 0.0, 1.0)
        cov = hit.astype(np.float64)
        rgb, cov = rgb.astype(np.float32), cov.astype(np.float32)
        if ss > 1:  # the box filter: INTER_AREA at an integer factor is the mean of each ss x ss block
            rgb = cv2.resize(rgb, (width, height), interpolation=cv2.INTER_AREA)
            cov = cv2.resize(cov, (width, height), interpolation=cv2.INTER_AREA)
        return rgb, cov

    def frame(self, verts_samples: list[np.ndarray], viewmat: np.ndarray, K: np.ndarray, width: int, height: int,
              index: int, frames: int, supersample: int = 2) -> tuple[np.ndarray, np.ndarray]:
        """What the phone recorded at frame ``index`` of ``frames``: the person at each shutter sample's posed
        vertices (averaged: motion blur) over the room, through the sensor. -> (frame [H, W, 3], person
        coverage [H, W])"""
        rgb = np.zeros((height, width, 3), np.float32)
        cov = np.zeros((height, width), np.float32)
        for verts in verts_samples:
            r, c = self.person(verts, viewmat, K, width, height, supersample)
            rgb += r / len(verts_samples)
            cov += c / len(verts_samples)
        background = self.room.render(viewmat, K, width, height)
        light = rgb + (1.0 - cov)[..., None] * background
        return self.sensor.record(light, index, frames, self.seed), cov
