"""The geometry-aligned reference: real pixels of training frames carried through the body mesh to a
Generator draw (``Aligner``; the rules: docs/augmentation.md, "Pseudo-GT", "The aligned reference" and
"Masks and weights"; the knobs: ``AlignConfig``).
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass
from typing import Callable, Collection, NamedTuple

import cv2
import numpy as np

from trioman.runtime.mesh_raster import interpolate, rasterize_mesh, vertex_normals
from trioman.runtime.skeleton import SkinnedMesh
from trioman.runtime.texture_fusion import FusedTexture, fuse_texture

__all__ = ["AlignConfig", "Aligned", "SourceViews", "Aligner"]


@dataclass(frozen=True)
class AlignConfig:
    sources: int = 3  # frames fused per draw: the draw's own frame and the nearest others by viewing direction
    depth_tolerance: float = 0.03  # metres between the carried point and the source's visible body surface
    min_cosine: float = 0.25  # surface normal . direction to the source camera, below which a source is not used
    angle_power: float = 4.0  # fusion weight cosine ** angle_power
    own_frame_weight: float = 2.0  # the draw's own source frame counts this much more than the others
    flow: bool = True  # re-align the carried pixels to the coarse render by dense optical flow
    max_flow: float = 0.05  # longest accepted flow, as a fraction of the image's longer side
    flow_consistency: float = 1.0  # pixels: forward + backward flow longer than this drops the pixel
    band: float = 0.1  # off the body, the carried mask reaches this far (fraction of the image's longer side)
    cache: int = 64  # source frames whose posed body and depth are kept between draws
    texture: int = 0  # > 0: a texture of this many texels a side fused from every source frame
    # (runtime/texture_fusion.py) gives the colour wherever its texels were seen; the carried pixels elsewhere
    texture_smooth: float = 0.02  # the fused texture's smoothness weight
    texture_min_seen: float = 0.05  # a fused texel counts as seen from this total pixel weight on

    def __post_init__(self) -> None:
        if isinstance(self.sources, bool) or not isinstance(self.sources, int) or self.sources < 1:
            raise ValueError(f"sources: must be an integer >= 1, got {self.sources!r}")
        if isinstance(self.texture, bool) or not isinstance(self.texture, int) or not (self.texture == 0 or 16 <= self.texture <= 4096):
            raise ValueError(f"texture: 0 (off) or the fused texture's side in texels, 16 to 4096, got {self.texture!r}")
        for name in ("depth_tolerance", "max_flow", "band", "flow_consistency", "angle_power", "own_frame_weight",
                     "texture_smooth", "texture_min_seen"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v > 0):
                raise ValueError(f"{name}: must be a finite number > 0, got {v!r}")
        if not (isinstance(self.min_cosine, (int, float)) and 0.0 <= self.min_cosine < 1.0):
            raise ValueError(f"min_cosine: must lie in [0, 1), got {self.min_cosine!r}")


class Aligned(NamedTuple):
    rgb: np.ndarray  # [H, W, 3] float32: carried real colour where ``valid``, 0 elsewhere
    valid: np.ndarray  # [H, W] bool: a real pixel was carried here (and survived the re-alignment)
    body: np.ndarray  # [H, W] bool: the posed body mesh covers the pixel centre
    silhouette: np.ndarray  # [H, W] float32 in [0, 1]: the person at the draw (body mesh and carried source mask)

    @property
    def coverage(self) -> float:
        """Share of the body's pixels that hold a carried real pixel."""
        n = int(self.body.sum())
        return float((self.valid & self.body).sum()) / n if n else 0.0


@dataclass(frozen=True)
class SourceViews:
    """The frames pixels are carried from. image(p) -> [H, W, 3] colour premultiplied by the mask (on black),
    mask(p) -> [H, W] in [0, 1]; p is a position in these arrays."""

    image: Callable[[int], np.ndarray]
    mask: Callable[[int], np.ndarray]
    poses: np.ndarray  # [F, J, 3]
    trans: np.ndarray  # [F, 3]
    viewmat: np.ndarray  # [F, 4, 4]
    K: np.ndarray  # [F, 3, 3]
    width: int
    height: int

    def __len__(self) -> int:
        return len(self.poses)

    @classmethod
    def of_subject(cls, subject, indices: np.ndarray) -> "SourceViews":
        """A subject's frames ``indices`` [F] (runtime.formats.Subject) as source views, position p = indices[p]."""
        indices = np.asarray(indices)

        def image(p: int) -> np.ndarray:
            i = int(indices[p])
            return subject.image(i) * subject.mask(i)[..., None]

        return cls(image, lambda p: subject.mask(int(indices[p])), np.asarray(subject.poses)[indices],
                   np.asarray(subject.trans)[indices], np.asarray(subject.viewmat)[indices], np.asarray(subject.K)[indices],
                   subject.width, subject.height)


class _Posed(NamedTuple):
    vertices: np.ndarray  # [V, 3] world
    normals: np.ndarray  # [V, 3]
    depth: np.ndarray  # [H, W] the source camera's body depth (inf off the body)
    image: np.ndarray  # [H, W, 3] premultiplied
    mask: np.ndarray  # [H, W]


def _direction_in_body(mesh: SkinnedMesh, pose: np.ndarray, trans: np.ndarray, viewmat: np.ndarray) -> np.ndarray:
    """Unit direction from the body's root to the camera centre, in the root joint's frame. [3]."""
    T = mesh.skeleton.forward_kinematics(np.asarray(pose, np.float64), np.asarray(trans, np.float64))[0]  # [4, 4] root
    R, t = np.asarray(viewmat, np.float64)[:3, :3], np.asarray(viewmat, np.float64)[:3, 3]
    d = T[:3, :3].T @ (-R.T @ t - T[:3, 3])
    return d / max(float(np.linalg.norm(d)), 1e-12)


def _project(points: np.ndarray, viewmat: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """points [M, 3] world -> (x, y pixel coordinates with centres at +0.5, camera depth z), each [M]."""
    cam = points @ viewmat[:3, :3].T + viewmat[:3, 3]
    z = cam[:, 2]
    zs = np.where(z > 1e-6, z, 1e-6)
    x = K[0, 0] * cam[:, 0] / zs + K[0, 1] * cam[:, 1] / zs + K[0, 2]
    y = K[1, 1] * cam[:, 1] / zs + K[1, 2]
    return x, y, z


def _remap(img: np.ndarray, x: np.ndarray, y: np.ndarray, nearest: bool = False) -> np.ndarray:
    """Sample ``img`` at pixel coordinates (x, y) (centres at +0.5), zero outside. x, y: [...] float."""
    interp = cv2.INTER_NEAREST if nearest else cv2.INTER_LINEAR
    return cv2.remap(np.ascontiguousarray(img, dtype=np.float32), (x - 0.5).astype(np.float32), (y - 0.5).astype(np.float32),
                     interp, borderMode=cv2.BORDER_CONSTANT, borderValue=0)


class Aligner:
    """Carries real pixels of ``views`` to Generator draws through the body ``mesh`` (docs/augmentation.md,
    "Pseudo-GT")."""

    def __init__(self, mesh: SkinnedMesh, views: SourceViews, cfg: AlignConfig | None = None) -> None:
        self.mesh, self.views, self.cfg = mesh, views, cfg or AlignConfig()
        self.faces = np.asarray(mesh.faces)
        self._dirs = np.stack([_direction_in_body(mesh, views.poses[p], views.trans[p], views.viewmat[p])
                               for p in range(len(views))])
        self._cache: OrderedDict[int, _Posed] = OrderedDict()
        self._fused: FusedTexture | None = None

    @property
    def fused(self) -> FusedTexture:
        """The texture fused from every source view (``cfg.texture`` texels a side), made on first use."""
        if self._fused is None:
            v = self.views

            def frame(p: int) -> tuple:
                m = np.asarray(v.mask(p), np.float32)
                colour = np.asarray(v.image(p), np.float32) / np.maximum(m, 1e-6)[..., None]  # un-premultiplied
                return v.poses[p], v.trans[p], v.viewmat[p], v.K[p], colour, m

            self._fused = fuse_texture(self.mesh, len(v), frame, self.cfg.texture, self.cfg.texture_smooth)
        return self._fused

    def sources_for(self, own: int, pose: np.ndarray, trans: np.ndarray, viewmat: np.ndarray,
                    exclude: Collection[int] = ()) -> list[int]:
        """The draw's own frame first, then the frames whose camera sees the body from the nearest direction
        (none of ``exclude``)."""
        d = _direction_in_body(self.mesh, pose, trans, viewmat)
        skip = {int(own), *map(int, exclude)}
        order = [int(p) for p in np.argsort(-(self._dirs @ d), kind="stable") if int(p) not in skip]
        return [own] + order[: self.cfg.sources - 1]

    def _posed(self, p: int) -> _Posed:
        if p in self._cache:
            self._cache.move_to_end(p)
            return self._cache[p]
        v = self.views
        verts = self.mesh.pose(np.asarray(v.poses[p], np.float64), np.asarray(v.trans[p], np.float64))
        depth = rasterize_mesh(verts, self.faces, v.viewmat[p], v.K[p], v.width, v.height).depth
        posed = _Posed(verts, vertex_normals(verts, self.faces), depth, np.asarray(v.image(p), np.float32),
                       np.asarray(v.mask(p), np.float32))
        self._cache[p] = posed
        while len(self._cache) > self.cfg.cache:
            self._cache.popitem(last=False)
        return posed

    def align(self, own: int, pose: np.ndarray, trans: np.ndarray, viewmat: np.ndarray, K: np.ndarray,
              coarse: np.ndarray | None = None, exclude: Collection[int] = ()) -> Aligned:
        """The aligned reference at a draw (pose [J, 3], trans [3], viewmat [4, 4], K [3, 3]) of source frame
        position ``own``; ``coarse`` [H, W, 3]: the avatar's render at the draw, to re-align to (cfg.flow);
        ``exclude``: positions never used as the other sources (a Refiner's target frame)."""
        cfg, W, H = self.cfg, self.views.width, self.views.height
        if cfg.texture and exclude:
            raise ValueError("exclude: a fused texture holds every source frame; align with texture 0 to leave frames out")
        verts = self.mesh.pose(np.asarray(pose, np.float64), np.asarray(trans, np.float64))
        frags = rasterize_mesh(verts, self.faces, viewmat, K, W, H)
        body = frags.face_id >= 0
        if not body.any():
            empty = np.zeros((H, W), np.float32)
            return Aligned(np.zeros((H, W, 3), np.float32), np.zeros((H, W), bool), body, empty)
        acc = np.zeros((H, W, 3), np.float64)
        wsum = np.zeros((H, W), np.float64)
        own_xy = None
        for p in self.sources_for(own, pose, trans, viewmat, exclude):
            src = self._posed(p)
            pts = interpolate(frags, src.vertices, self.faces)[body].astype(np.float64)  # [M, 3]
            nrm = interpolate(frags, src.normals, self.faces)[body].astype(np.float64)
            R, t = self.views.viewmat[p][:3, :3].astype(np.float64), self.views.viewmat[p][:3, 3].astype(np.float64)
            x, y, z = _project(pts, self.views.viewmat[p].astype(np.float64), self.views.K[p].astype(np.float64))
            if p == own:
                own_xy = (x, y)
            to_cam = (-R.T @ t)[None] - pts
            cos = np.einsum("ij,ij->i", nrm, to_cam) / np.maximum(
                np.linalg.norm(nrm, axis=1) * np.linalg.norm(to_cam, axis=1), 1e-12)
            xs, ys = x.reshape(1, -1), y.reshape(1, -1)
            zbuf = _remap(np.where(np.isfinite(src.depth), src.depth, 0.0), xs, ys, nearest=True)[0]
            m = _remap(src.mask, xs, ys)[0]
            ok = (z > 0) & (np.abs(z - zbuf) < cfg.depth_tolerance) & (m > 0.5) & (cos >= cfg.min_cosine)
            col = _remap(src.image, xs, ys)[0] / np.maximum(m, 1e-6)[:, None]  # un-premultiplied colour
            w = np.where(ok, np.clip(cos, 0.0, 1.0) ** cfg.angle_power, 0.0) * (cfg.own_frame_weight if p == own else 1.0)
            acc[body] += w[:, None] * col
            wsum[body] += w
        valid = wsum > 0
        rgb = np.where(valid[..., None], acc / np.maximum(wsum, 1e-12)[..., None], 0.0).astype(np.float32)
        rgb = np.clip(rgb, 0.0, 1.0)
        silhouette = self._silhouette(own, body, own_xy)
        if cfg.flow and coarse is not None and valid.any():
            rgb, valid = self._realign(rgb, valid, np.asarray(coarse, np.float32))
        if cfg.texture:
            fused, seen = self.fused.render(self.mesh, pose, trans, viewmat, K, W, H, cfg.texture_min_seen)
            seen &= body
            rgb, valid = np.where(seen[..., None], fused, rgb).astype(np.float32), valid | seen
        return Aligned(rgb, valid, body, silhouette)

    def _silhouette(self, own: int, body: np.ndarray, own_xy: tuple[np.ndarray, np.ndarray] | None) -> np.ndarray:
        """Body mesh coverage, plus the own source frame's mask beyond its body carried off the body with the
        nearest body pixel's displacement, up to ``band`` off the body: the body's coverage alone on a subject
        whose clothing is painted on, the clothing too on a real capture. [H, W] float32."""
        H, W = body.shape
        if own_xy is None or not body.any():
            return body.astype(np.float32)
        jj, ii = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
        dx, dy = np.zeros((H, W), np.float32), np.zeros((H, W), np.float32)
        dx[body], dy[body] = own_xy[0] - jj[body], own_xy[1] - ii[body]
        dist, labels = cv2.distanceTransformWithLabels((~body).astype(np.uint8), cv2.DIST_L2, 5,
                                                       labelType=cv2.DIST_LABEL_PIXEL)
        # label -> the body pixel it belongs to (labels count the zero pixels in row-major order from 1)
        flat = np.flatnonzero(body.reshape(-1))
        nearest = flat[labels.reshape(-1) - 1]
        dxf, dyf = dx.reshape(-1)[nearest].reshape(H, W), dy.reshape(-1)[nearest].reshape(H, W)
        src = self._posed(own)
        beyond = np.where(np.isfinite(src.depth), 0.0, src.mask)  # the person beyond the source's body silhouette
        carried = np.where(dist <= self.cfg.band * max(H, W), _remap(beyond, jj + dxf, ii + dyf), 0.0)
        return np.where(body, 1.0, np.clip(carried, 0.0, 1.0)).astype(np.float32)

    def _realign(self, rgb: np.ndarray, valid: np.ndarray, coarse: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Warp the carried pixels onto the coarse render by forward/backward DIS flow on both images' detail
        (each minus its blur, so shading differences do not pull). Where the flow is consistent and short the
        warped pixel is taken; where it is not, a pixel on texture is dropped, one on flat colour (where flow
        is undefined and a shift changes nothing) is kept as the mesh carried it."""
        H, W = valid.shape
        filled = np.where(valid[..., None], rgb, coarse)
        a, b = (_detail(x) for x in (coarse, filled))
        dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
        fwd = dis.calc(a, b, None)  # coarse pixel -> where its content lies in the carried image
        bwd = dis.calc(b, a, None)
        jj, ii = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
        x, y = jj + fwd[..., 0], ii + fwd[..., 1]
        back = np.stack([_remap(bwd[..., k], x, y) for k in range(2)], -1)
        flowed = (np.linalg.norm(fwd + back, axis=-1) <= self.cfg.flow_consistency) & \
                 (np.linalg.norm(fwd, axis=-1) <= self.cfg.max_flow * max(H, W))
        flowed &= _remap(valid.astype(np.float32), x, y, nearest=True) > 0.5
        warped = np.stack([_remap(filled[..., k], x, y) for k in range(3)], -1)
        flat = _texture(coarse) < _FLAT
        ok = valid & (flowed | flat)
        out = np.where(flowed[..., None], warped, rgb)
        return np.where(ok[..., None], np.clip(out, 0.0, 1.0), 0.0).astype(np.float32), ok


_FLAT = 0.02  # local contrast (std of the detail over a 5x5 window) below which a pixel is flat colour


def _detail(img: np.ndarray) -> np.ndarray:
    """Grey-level detail (the image minus its 3 px blur) as uint8 about 128, for optical flow."""
    g = cv2.cvtColor(np.asarray(img, np.float32), cv2.COLOR_RGB2GRAY)
    d = g - cv2.GaussianBlur(g, (0, 0), 3.0)
    return np.clip(128 + 255 * 2 * d, 0, 255).astype(np.uint8)


def _texture(img: np.ndarray) -> np.ndarray:
    """Local contrast [H, W]: the standard deviation of the grey-level detail over a 5 x 5 window."""
    g = cv2.cvtColor(np.asarray(img, np.float32), cv2.COLOR_RGB2GRAY)
    d = g - cv2.GaussianBlur(g, (0, 0), 3.0)
    mean = cv2.blur(d, (5, 5))
    return np.sqrt(np.maximum(cv2.blur(d * d, (5, 5)) - mean * mean, 0.0))
