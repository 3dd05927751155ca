"""The Generator (paper 3.2.3): Gaussian perturbations of a frame's pose and camera, ``sample``'s candidates.

The joint groups, sigmas, clamps and draw order: docs/design.md, "Generator (3.2.3)".
"""

from __future__ import annotations

import math
import numbers
import re
from dataclasses import dataclass, field
from typing import Mapping

import numpy as np

from trioman.runtime.cameras import camera_center
from trioman.runtime.rotations import axis_angle_to_matrix
from trioman.runtime.skeleton import Skeleton

__all__ = [
    "GROUPS",
    "DEFAULT_POSE_SIGMA",
    "DEFAULT_MAX_ANGLE",
    "GeneratorConfig",
    "CameraDelta",
    "Candidate",
    "joint_group",
    "joint_groups",
    "subject_center",
    "perturb_pose",
    "orbit_camera",
    "perturb_camera",
    "sample",
]

# Match order: the first group whose tokens meet the name's tokens wins ("root" is joint 0 only,
# "other" is the fallback).
GROUPS = ("root", "hands", "head", "arms", "legs", "torso", "other")
_GROUP_TOKENS: dict[str, frozenset[str]] = {
    "hands": frozenset({"wrist", "finger", "metacarpal", "hand", "thumb", "index", "middle", "ring", "pinky"}),
    "head": frozenset({"head", "eye", "jaw", "tongue", "levator", "oculi", "orbicularis", "oris",
                       "risorius", "temporalis", "special"}),
    "arms": frozenset({"clavicle", "collar", "shoulder", "upperarm", "lowerarm", "arm", "forearm", "elbow"}),
    "legs": frozenset({"upperleg", "lowerleg", "leg", "thigh", "hip", "knee", "ankle", "foot", "toe"}),
    "torso": frozenset({"spine", "pelvis", "neck", "chest"}),
}
_MAX_VALUE = 1e6  # cap on every config number: keeps sigma * N(0, 1) far from float overflow
DEFAULT_POSE_SIGMA: Mapping[str, float] = {
    "root": 0.0, "hands": 0.10, "head": 0.10, "arms": 0.15, "legs": 0.08, "torso": 0.05, "other": 0.05,
}
DEFAULT_MAX_ANGLE: Mapping[str, float] = {
    "root": math.pi, "hands": 1.6, "head": 0.8, "arms": 2.5, "legs": 2.0, "torso": 0.6, "other": 0.6,
}


def _finite_nonneg(name: str, value: object) -> float:
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or not 0 <= value <= _MAX_VALUE:
        raise ValueError(f"{name}: must be a number in [0, {_MAX_VALUE:g}], got {value!r}")
    return float(value)


def _per_group(name: str, given: Mapping[str, float], defaults: Mapping[str, float]) -> dict[str, float]:
    unknown = sorted(set(given) - set(GROUPS))
    if unknown:
        raise ValueError(f"{name}: unknown group(s) {unknown}; expected keys from {list(GROUPS)}")
    return {g: _finite_nonneg(f"{name}[{g!r}]", given.get(g, defaults[g])) for g in GROUPS}


@dataclass(frozen=True)
class GeneratorConfig:
    """Sampling parameters (defaults and clamps: docs/design.md, "Generator (3.2.3)").

    ``pose_sigma`` and ``max_angle`` map group names (``GROUPS``) to radians; groups left out keep
    their defaults, so ``GeneratorConfig(pose_sigma={"arms": 0.3})`` changes the arms only.
    """

    pose_sigma: Mapping[str, float] = field(default_factory=dict)
    max_angle: Mapping[str, float] = field(default_factory=dict)
    azimuth_sigma: float = 0.5  # radians
    elevation_sigma: float = 0.15  # radians
    distance_sigma: float = 0.1  # log-distance
    max_elevation: float = 1.3  # radians, in (0, pi/2)
    max_distance_ratio: float = 2.0  # >= 1
    min_distance: float = 0.3  # metres, > 0

    def __post_init__(self) -> None:
        object.__setattr__(self, "pose_sigma", _per_group("pose_sigma", self.pose_sigma, DEFAULT_POSE_SIGMA))
        max_angle = _per_group("max_angle", self.max_angle, DEFAULT_MAX_ANGLE)
        for g, a in max_angle.items():
            if not 0 < a <= math.pi:
                raise ValueError(f"max_angle[{g!r}]: must lie in (0, pi], got {a!r}")
        object.__setattr__(self, "max_angle", max_angle)
        for name in ("azimuth_sigma", "elevation_sigma", "distance_sigma"):
            _finite_nonneg(name, getattr(self, name))
        if not 0 < _finite_nonneg("max_elevation", self.max_elevation) < math.pi / 2:
            raise ValueError(f"max_elevation: must lie in (0, pi/2), got {self.max_elevation!r}")
        if not _finite_nonneg("max_distance_ratio", self.max_distance_ratio) >= 1:
            raise ValueError(f"max_distance_ratio: must be >= 1, got {self.max_distance_ratio!r}")
        if not _finite_nonneg("min_distance", self.min_distance) > 0:
            raise ValueError(f"min_distance: must be > 0, got {self.min_distance!r}")


@dataclass(frozen=True)
class CameraDelta:
    """Applied camera perturbation (after the clamps), recorded for provenance."""

    azimuth: float  # radians, wrapped to [-pi, pi)
    elevation: float  # radians
    log_distance: float  # new distance = old distance * exp(log_distance)


@dataclass(frozen=True, eq=False)
class Candidate:
    """One Generator sample: the new pose and camera, and what was applied to get them."""

    pose: np.ndarray  # [J, 3] axis-angle
    trans: np.ndarray  # [3]
    viewmat: np.ndarray  # [4, 4] world->camera
    delta_pose: np.ndarray  # [J, 3] applied pose change, pose - input pose (after the clamp)
    camera: CameraDelta
    center: np.ndarray  # [3] orbit centre (world)


# --------------------------------------------------------------------------------------------
# groups and centre


def joint_group(name: str) -> str:
    """The group of a non-root joint name (its tokens against ``GROUPS``); ``"other"`` when none matches."""
    tokens = set(re.split(r"[^a-z]+", name.lower()))
    for group in GROUPS[1:-1]:
        if tokens & _GROUP_TOKENS[group]:
            return group
    return "other"


def joint_groups(skeleton: Skeleton) -> tuple[str, ...]:
    """[J] group per joint: joint 0 is ``"root"``, the others by ``joint_group``."""
    return ("root",) + tuple(joint_group(n) for n in skeleton.joint_names[1:])


def _check_frame(skeleton: Skeleton, pose: np.ndarray, trans: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    pose, trans = skeleton.check_pose(pose, trans)
    if pose.ndim != 2:
        raise ValueError(f"pose: expected one frame [{skeleton.num_joints}, 3], got {list(pose.shape)}")
    return pose, trans


def subject_center(skeleton: Skeleton, pose: np.ndarray, trans: np.ndarray) -> np.ndarray:
    """Centre of the bounding box of the posed joints (FK). pose [J, 3], trans [3] -> [3]."""
    pose, trans = _check_frame(skeleton, pose, trans)
    p = skeleton.forward_kinematics(pose, trans)[:, :3, 3]
    return 0.5 * (p.min(axis=0) + p.max(axis=0))


# --------------------------------------------------------------------------------------------
# pose


def _norm3(v: np.ndarray) -> np.ndarray:
    """Overflow-free Euclidean norm over the last axis of [..., 3]."""
    return np.hypot(np.hypot(v[..., 0], v[..., 1]), v[..., 2])


def _clamp_pose(pose: np.ndarray, new: np.ndarray, max_angle: np.ndarray) -> np.ndarray:
    """Scale rows of ``new`` whose angle exceeds max(max_angle, |pose|) back onto that bound."""
    bound = np.maximum(max_angle, _norm3(pose))
    angle = _norm3(new)
    over = angle > bound
    scale = np.where(over, bound / np.where(over, angle, 1.0), 1.0)
    return new * scale[:, None]


def _pose_noise(skeleton: Skeleton, rng: np.random.Generator, cfg: GeneratorConfig) -> tuple[np.ndarray, np.ndarray]:
    """Raw noise [J, 3] and per-joint max angle [J]."""
    groups = joint_groups(skeleton)
    sigma = np.array([cfg.pose_sigma[g] for g in groups])
    max_angle = np.array([cfg.max_angle[g] for g in groups])
    return rng.standard_normal((skeleton.num_joints, 3)) * sigma[:, None], max_angle


def perturb_pose(
    skeleton: Skeleton,
    pose: np.ndarray,  # [J, 3] axis-angle
    trans: np.ndarray,  # [3]
    rng: np.random.Generator,
    cfg: GeneratorConfig | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """theta + Delta theta with per-group Gaussian Delta, clamped. -> (pose [J, 3], trans [3])."""
    cfg = cfg or GeneratorConfig()
    pose, trans = _check_frame(skeleton, pose, trans)
    noise, max_angle = _pose_noise(skeleton, rng, cfg)
    return _clamp_pose(pose, pose + noise, max_angle), trans.copy()


# --------------------------------------------------------------------------------------------
# camera


def _check_viewmat(viewmat: np.ndarray) -> np.ndarray:
    viewmat = np.asarray(viewmat, dtype=np.float64)
    if viewmat.shape != (4, 4):
        raise ValueError(f"viewmat: expected shape [4, 4], got {list(viewmat.shape)}")
    bad = int(np.count_nonzero(~np.isfinite(viewmat)))
    if bad:
        raise ValueError(f"viewmat: {bad} non-finite value(s) (NaN/Inf)")
    R = viewmat[:3, :3]
    err = float(np.abs(R @ R.T - np.eye(3)).max())
    if err > 1e-6 or np.linalg.det(R) < 0 or np.any(viewmat[3] != (0.0, 0.0, 0.0, 1.0)):
        raise ValueError(f"viewmat: expected a rigid world->camera transform (orthonormality error {err:.2e})")
    return viewmat


def _check_center(center: np.ndarray) -> np.ndarray:
    center = np.asarray(center, dtype=np.float64)
    if center.shape != (3,) or not np.isfinite(center).all():
        raise ValueError(f"center: expected 3 finite values, got {center.tolist()}")
    return center


def _orbit_frame(viewmat: np.ndarray, center: np.ndarray) -> tuple[np.ndarray, float, float]:
    """Camera offset from the centre, its distance and elevation (radians)."""
    offset = camera_center(viewmat) - center
    distance = float(_norm3(offset))
    if not distance > 1e-9:
        raise ValueError(f"center: the camera sits at the orbit centre {center.tolist()}")
    horizontal = float(np.hypot(offset[0], offset[1]))
    if horizontal <= 1e-9 * distance:
        raise ValueError("viewmat: the camera is straight above or below the centre; the orbit azimuth is undefined")
    return offset, distance, math.atan2(offset[2], horizontal)


def orbit_camera(
    viewmat: np.ndarray,  # [4, 4] world->camera
    center: np.ndarray,  # [3] world
    d_azimuth: float,
    d_elevation: float,
    log_distance: float,
) -> np.ndarray:  # [4, 4]
    """Move the camera rigidly about ``center``: turn by ``d_azimuth`` about world z, raise by
    ``d_elevation`` (radians) and scale its distance by exp(``log_distance``); no clamps."""
    viewmat = _check_viewmat(viewmat)
    center = _check_center(center)
    offset, _, _ = _orbit_frame(viewmat, center)
    tangent = np.array([offset[1], -offset[0], 0.0])  # u x z for u the horizontal direction
    tangent /= _norm3(tangent)
    R = axis_angle_to_matrix(np.array([0.0, 0.0, d_azimuth])) @ axis_angle_to_matrix(tangent * d_elevation)
    eye = center + math.exp(log_distance) * (R @ offset)
    rot = viewmat[:3, :3] @ R.T  # camera axes turn with the orbit
    out = np.eye(4)
    out[:3, :3] = rot
    out[:3, 3] = -rot @ eye
    return out


def _camera_delta(
    viewmat: np.ndarray, center: np.ndarray, noise: np.ndarray, cfg: GeneratorConfig
) -> CameraDelta:
    """Clamp raw camera noise [3] (azimuth, elevation, log-distance) for this camera."""
    _, distance, elevation = _orbit_frame(viewmat, center)
    limit = max(cfg.max_elevation, abs(elevation))
    d_el = float(np.clip(elevation + noise[1], -limit, limit)) - elevation
    max_log = math.log(cfg.max_distance_ratio)
    d_log = float(np.clip(noise[2], -max_log, max_log))
    d_log = max(d_log, math.log(min(distance, cfg.min_distance) / distance))
    d_az = (float(noise[0]) + math.pi) % (2 * math.pi) - math.pi
    return CameraDelta(d_az, d_el, d_log)


def _camera_noise(rng: np.random.Generator, cfg: GeneratorConfig) -> np.ndarray:
    return rng.standard_normal(3) * np.array([cfg.azimuth_sigma, cfg.elevation_sigma, cfg.distance_sigma])


def _perturb_camera(
    viewmat: np.ndarray, center: np.ndarray, rng: np.random.Generator, cfg: GeneratorConfig
) -> tuple[np.ndarray, CameraDelta]:
    viewmat = _check_viewmat(viewmat)
    center = _check_center(center)
    delta = _camera_delta(viewmat, center, _camera_noise(rng, cfg), cfg)
    return orbit_camera(viewmat, center, delta.azimuth, delta.elevation, delta.log_distance), delta


def perturb_camera(
    viewmat: np.ndarray,  # [4, 4] world->camera
    center: np.ndarray,  # [3] world
    rng: np.random.Generator,
    cfg: GeneratorConfig | None = None,
) -> np.ndarray:  # [4, 4]
    """pi + Delta pi: Gaussian azimuth, elevation and log-distance about ``center``, clamped."""
    return _perturb_camera(viewmat, center, rng, cfg or GeneratorConfig())[0]


# --------------------------------------------------------------------------------------------
# candidates


def _as_rng(seed: int | np.random.Generator) -> np.random.Generator:
    if isinstance(seed, np.random.Generator):
        return seed
    if isinstance(seed, bool) or not isinstance(seed, numbers.Integral) or seed < 0:
        raise ValueError(f"seed: expected an integer >= 0 or a numpy Generator, got {seed!r}")
    return np.random.default_rng(int(seed))


def sample(
    skeleton: Skeleton,
    pose: np.ndarray,  # [J, 3] the frame's pose
    trans: np.ndarray,  # [3]
    viewmat: np.ndarray,  # [4, 4] the frame's camera
    seed: int | np.random.Generator,
    n: int = 2,
    cfg: GeneratorConfig | None = None,
) -> list[Candidate]:
    """``n`` perturbed (pose, camera) candidates of one frame (the paper draws two per frame).

    The orbit centre is ``subject_center`` of the frame's own pose, shared by all candidates.
    """
    cfg = cfg or GeneratorConfig()
    if isinstance(n, bool) or not isinstance(n, numbers.Integral) or n < 1:
        raise ValueError(f"n: expected an integer >= 1, got {n!r}")
    pose, trans = _check_frame(skeleton, pose, trans)
    rng = _as_rng(seed)
    center = subject_center(skeleton, pose, trans)
    out = []
    for _ in range(n):
        new_pose, new_trans = perturb_pose(skeleton, pose, trans, rng, cfg)
        new_view, delta = _perturb_camera(viewmat, center, rng, cfg)
        out.append(Candidate(new_pose, new_trans, new_view, new_pose - pose, delta, center.copy()))
    return out


def keep_detail(coarse: np.ndarray, refined: np.ndarray, sigma: float) -> np.ndarray:
    """The refined frames' detail on the coarse frames: coarse + d - blur(d), d = refined - coarse, blurred
    by a Gaussian of ``sigma`` pixels (reflected borders). [N, H, W, 3] float32 in [0, 1] each -> the same,
    clipped to [0, 1]. A change constant over the image (a colour shift) is removed; changes finer than
    ``sigma`` pass."""
    import cv2

    if coarse.shape != refined.shape or coarse.ndim != 4 or coarse.shape[-1] != 3:
        raise ValueError(f"refined: expected the coarse frames' shape [N, H, W, 3], got {refined.shape} and {coarse.shape}")
    if not (np.isfinite(sigma) and sigma > 0):
        raise ValueError(f"sigma: must be a finite number > 0 (pixels), got {sigma!r}")
    d = (refined - coarse).astype(np.float32)
    low = np.stack([cv2.GaussianBlur(x, (0, 0), sigmaX=float(sigma), borderType=cv2.BORDER_REFLECT) for x in d])
    return np.clip(coarse + d - low, 0.0, 1.0).astype(np.float32)
