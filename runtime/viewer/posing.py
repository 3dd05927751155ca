"""What the viewer shows, in numpy: the pose its controls ask for and the splat arrays that changed.

A pose is a frame of the selected motion, or the rest pose (zero rotations, zero translation), then bent
by hand: each joint group of ``trioman.runtime.generator.GROUPS`` has a slider in degrees; the group's
base joints (those whose parent is in another group: a clavicle, an upper leg, the neck) turn by that
angle about the group's world axis (``BEND_AXES``), applied after the motion's rotation, so the group
bends at its base and keeps its own shape; joints on the right side turn by the mirror image (about
the x = 0 plane), so a slider bends both sides alike. ``SplatDiff`` turns posed Gaussians into the splat arrays a client draws
(centres, covariances, colours, opacities) and reports only the arrays that changed since the last update.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping, NamedTuple

import numpy as np

from trioman.runtime.avatar import Avatar, Gaussians
from trioman.runtime.generator import joint_groups
from trioman.runtime.motions import DEFAULT_FRAMES, MOTIONS, Motion
from trioman.runtime.rotations import axis_angle_to_matrix, matrix_to_axis_angle, quat_to_matrix

# The world axis (0 x, 1 y, 2 z) each group's slider turns about: the root turns about z (up), arms
# rise and fall about y (they hang along x), the rest bend forward and back about x.
BEND_AXES: Mapping[str, int] = {"root": 2, "torso": 0, "head": 0, "arms": 1, "legs": 0, "hands": 0, "other": 0}
MAX_BEND = 180.0  # degrees, either way
SUBJECT_MOTION = "test poses"  # picker label prefix of a subject's test poses
REST_MOTION = "rest"  # the picker's one entry when no motion fits the skeleton

_RIGHT = re.compile(r"(^right|^r_|[._]r$|_r_|\.r\.)", re.IGNORECASE)  # Anny "upperarm01.R", SMPL-X "right_elbow"


def is_right(name: str) -> bool:
    """A joint on the subject's right side (mirrored by the bend sliders)."""
    return bool(_RIGHT.search(name))


def group_bases(groups: tuple[str, ...], parents: np.ndarray) -> np.ndarray:
    """[J] bool: joints whose parent lies in another group (or that have none)."""
    parents = np.asarray(parents)
    names = np.array(groups)
    return (parents < 0) | (names != names[np.maximum(parents, 0)])


def bend_pose(pose: np.ndarray, groups: tuple[str, ...], bases: np.ndarray, right: np.ndarray,
              bends: Mapping[str, float]) -> np.ndarray:
    """pose [J, 3] axis-angle, groups [J] group names, bases [J] bool (``group_bases``), right [J] bool, bends
    group -> degrees -> [J, 3] float64."""
    unknown = sorted(set(bends) - set(BEND_AXES))
    if unknown:
        raise ValueError(f"bends: unknown group(s) {unknown}; expected keys from {list(BEND_AXES)}")
    out = np.array(pose, dtype=np.float64)
    for group, degrees in bends.items():
        if not np.isfinite(degrees) or abs(degrees) > MAX_BEND:
            raise ValueError(f"bends[{group!r}]: must be finite degrees in [-{MAX_BEND:g}, {MAX_BEND:g}], got {degrees}")
        joints = np.flatnonzero((np.array(groups) == group) & bases)
        if degrees == 0 or len(joints) == 0:
            continue
        aa = np.zeros((len(joints), 3))
        aa[:, BEND_AXES[group]] = np.deg2rad(degrees)
        aa[right[joints], 1:] *= -1.0  # mirror about x = 0: (a_x, a_y, a_z) -> (a_x, -a_y, -a_z)
        out[joints] = matrix_to_axis_angle(axis_angle_to_matrix(aa) @ axis_angle_to_matrix(out[joints]))
    return out


@dataclass
class PoseControls:
    """The viewer's pose controls: a frame of the selected motion or the rest pose, bends in degrees."""

    frame: int = 0
    rest: bool = False
    pose_dependent: bool = True
    bends: dict[str, float] = field(default_factory=dict)


def motion_catalog(skeleton, motion: str | None = None, subject: str | os.PathLike | None = None) -> dict[str, Motion]:
    """The motion picker's entries, label -> motion in the skeleton's joint order: the shipped motions the
    skeleton can play (those naming joints it lacks are left out), the motion file or subject folder given
    with ``motion`` (a shipped name only selects), and ``subject``'s test poses. With none of these, one
    frame of the rest pose (``REST_MOTION``)."""
    from trioman.runtime.formats.motion import motion_from_spec, motion_from_subject

    catalog: dict[str, Motion] = {}
    for name, make in MOTIONS.items():
        try:
            catalog[name] = make(skeleton, DEFAULT_FRAMES[name]).for_skeleton(skeleton)
        except ValueError:  # the motion turns a joint this skeleton lacks
            continue
    if motion is not None and motion not in MOTIONS:
        catalog[motion_label(motion)] = motion_from_spec(motion, skeleton)
    elif motion is not None and motion not in catalog:
        raise ValueError(f"motion {motion}: the shipped motion turns joints this avatar's skeleton lacks "
                         f"({skeleton.num_joints} joints); playable: {list(catalog) or 'none'}")
    if subject is not None:
        catalog[f"{SUBJECT_MOTION}: {Path(subject).name}"] = motion_from_subject(subject, "test").for_skeleton(skeleton)
    if not catalog:
        J = skeleton.num_joints
        catalog[REST_MOTION] = Motion(REST_MOTION, np.zeros((1, J, 3), np.float32), np.zeros((1, 3), np.float32),
                                      skeleton.joint_names)
    return catalog


def motion_label(spec: str) -> str:
    """The picker label of a ``--motion`` spec: a shipped name, else the file or folder name."""
    return spec if spec in MOTIONS else (Path(spec).name or spec)


class Poser:
    """The pose of one avatar under the viewer's controls, over a catalog of motions (``motion_catalog``)."""

    def __init__(self, avatar: Avatar, catalog: Mapping[str, Motion]):
        if not catalog:
            raise ValueError("catalog: no motions to pick from")
        self.avatar = avatar
        self.catalog = dict(catalog)
        self.groups = joint_groups(avatar.skeleton)
        self.bases = group_bases(self.groups, avatar.skeleton.parents)
        self.right = np.array([is_right(n) for n in avatar.skeleton.joint_names])
        self.name = next(iter(self.catalog))

    @property
    def bend_groups(self) -> tuple[str, ...]:
        """The groups with at least one joint, in BEND_AXES order."""
        return tuple(g for g in BEND_AXES if g in self.groups)

    def select(self, name: str) -> Motion:
        """Pick a motion by its label. -> the motion."""
        if name not in self.catalog:
            raise ValueError(f"motion: unknown entry {name!r}; have {list(self.catalog)}")
        self.name = name
        return self.catalog[name]

    @property
    def motion(self) -> Motion:
        return self.catalog[self.name]

    def pose(self, controls: PoseControls) -> tuple[np.ndarray, np.ndarray]:
        """-> pose [J, 3], trans [3] (float64) for the controls."""
        J = self.avatar.skeleton.num_joints
        if controls.rest:
            pose, trans = np.zeros((J, 3)), np.zeros(3)
        else:
            m = self.motion
            if not 0 <= controls.frame < m.num_frames:
                raise ValueError(f"frame: {controls.frame} is out of range for {self.name!r} ({m.num_frames} frames)")
            pose, trans = m.pose[controls.frame], m.trans[controls.frame]
        return bend_pose(pose, self.groups, self.bases, self.right, controls.bends), np.asarray(trans, dtype=np.float64)

    def gaussians(self, controls: PoseControls) -> Gaussians:
        pose, trans = self.pose(controls)
        return self.avatar.gaussians(pose, trans, pose_dependent=controls.pose_dependent)


class Splats(NamedTuple):
    """What a splat client draws (float32)."""

    centers: np.ndarray  # [N, 3] world (m)
    covariances: np.ndarray  # [N, 3, 3] R S S^T R^T (m^2)
    rgbs: np.ndarray  # [N, 3] in [0, 1]
    opacities: np.ndarray  # [N, 1] in [0, 1]


def covariances(quats: np.ndarray, scales: np.ndarray) -> np.ndarray:
    """quats [N, 4] wxyz, scales [N, 3] -> R diag(s^2) R^T [N, 3, 3] float32."""
    if np.all(quats[:, 0] == 1.0):  # identity rotations (isotropic avatars): the diagonal alone
        cov = np.zeros((len(scales), 3, 3), np.float32)
        idx = np.arange(3)
        cov[:, idx, idx] = np.square(scales, dtype=np.float32)
        return cov
    R = quat_to_matrix(quats.astype(np.float64))
    M = R * scales.astype(np.float64)[:, None, :]
    return np.einsum("nij,nkj->nik", M, M).astype(np.float32)


class SplatDiff:
    """The splat arrays last sent to the client; ``update`` returns those a new pose changed.

    Covariances are recomputed only when the rotations or scales changed (an isotropic avatar without
    pose-dependent scales keeps them for good), colours only with pose-dependent colour deltas.
    """

    def __init__(self) -> None:
        self._last: dict[str, np.ndarray] = {}

    def update(self, g: Gaussians) -> dict[str, np.ndarray]:
        """g: posed Gaussians -> the changed arrays by Splats field name (all of them on the first call)."""
        new = {"centers": g.means, "rgbs": g.colors, "opacities": g.opacities[:, None]}
        rot = {"quats": g.quats, "scales": g.scales}
        if any(k not in self._last or not np.array_equal(self._last[k], v) for k, v in rot.items()):
            new["covariances"] = covariances(g.quats, g.scales)
        changed = {k: np.ascontiguousarray(v, dtype=np.float32) for k, v in new.items()
                   if k not in self._last or not np.array_equal(self._last[k], v)}
        self._last.update(changed)
        self._last.update({k: v for k, v in rot.items()})
        return changed
