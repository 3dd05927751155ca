"""One image of an avatar at a pose and a camera (``trioman render``), no torch.

pose:   ``rest``; ``MOTION@I``, frame I of a shipped motion or a motion .npz (``@I`` optional, 0);
        ``SUBJECT@I``, frame I of a subject folder (its stored pose).
camera: ``front``, ``AZ,EL`` in degrees about the posed body (0,0 = in front, framed to fit), or ``subject`` (the
        camera of the subject frame given with ``pose``).

Errors name the parameter (``pose ...:``, ``camera ...:``, ``size:``); the command shows them with its flags.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import NamedTuple

import numpy as np

from trioman.runtime.animate import EMPTY_ALPHA, RenderOptions, parse_background
from trioman.runtime.cameras import frame_points
from trioman.runtime.avatar import Avatar
from trioman.runtime.formats import load_subject
from trioman.runtime.formats.motion import motion_from_spec
from trioman.runtime.motions import Motion
from trioman.runtime.render import rasterize
from trioman.runtime.skeleton import Skeleton

FRONT = (0.0, 5.0)  # the "front" camera: azimuth and elevation, degrees


class Still(NamedTuple):
    rgb: np.ndarray  # [H, W, 3] float32 in [0, 1]
    width: int
    height: int


def pose_source(spec: str) -> str | None:
    """The motion or subject a ``pose`` spec reads (None for ``rest``)."""
    return None if spec == "rest" else split_frame(spec)[0]


def split_frame(spec: str) -> tuple[str, int]:
    """``SOURCE@I`` -> (SOURCE, I); no ``@``: frame 0."""
    source, sep, frame = spec.rpartition("@")
    if not sep:
        return spec, 0
    try:
        return source, int(frame)
    except ValueError:
        raise ValueError(f"pose: frame after '@' must be an integer, got {frame!r} in {spec!r}") from None


def resolve_pose(spec: str, skeleton: Skeleton):
    """-> (pose [J, 3], trans [3], subject camera (K, viewmat, width, height) or None)."""
    if spec == "rest":
        return np.zeros((skeleton.num_joints, 3)), np.zeros(3), None
    source, i = split_frame(spec)
    if Path(source).is_dir():
        subject = load_subject(source, check_images=False)
        if not 0 <= i < subject.num_frames:
            raise ValueError(f"pose: frame {i} is out of range for {source} ({subject.num_frames} frames)")
        frames = Motion(source, np.array(subject.poses), np.array(subject.trans),
                        subject.body.skeleton.joint_names).for_skeleton(skeleton)  # joints matched by name
        cam = (np.array(subject.K[i]), np.array(subject.viewmat[i]), subject.width, subject.height)
        return frames.pose[i], frames.trans[i], cam
    motion = motion_from_spec(source, skeleton)
    if not 0 <= i < motion.num_frames:
        raise ValueError(f"pose: frame {i} is out of range for {source!r} ({motion.num_frames} frames)")
    return motion.pose[i], motion.trans[i], None


def render_still(avatar: Avatar, pose: str = "rest", cfg: RenderOptions | None = None) -> Still:
    """``avatar`` at the ``pose`` spec through ``cfg.camera``; an image that shows nothing of it is a ValueError."""
    cfg = cfg if cfg is not None else RenderOptions()
    p, trans, subject_cam = resolve_pose(pose, avatar.skeleton)
    g = avatar.gaussians(p, trans, pose_dependent=cfg.pose_dependent)
    if cfg.camera == "subject":
        if subject_cam is None:
            raise ValueError("camera: 'subject' needs `pose` SUBJECT@FRAME (the camera comes from that frame)")
        K, viewmat, width, height = subject_cam
        if cfg.size is not None:  # keep the view, change the resolution
            s = cfg.size / max(width, height)
            K = K.copy()
            K[:2] *= s
            width, height = round(width * s), round(height * s)
    else:
        az, el = FRONT if cfg.camera == "front" else _angles(cfg.camera)
        width = height = cfg.size or 512
        try:
            K, viewmat, _ = frame_points(g.means, (width, height), np.deg2rad(az), np.deg2rad(el))
        except ValueError as err:
            raise ValueError(f"pose {pose}: the avatar cannot be framed: {err}") from None
    r = rasterize(*g, viewmat, K, width, height, background=parse_background(cfg.background))
    if not r.alpha.max() >= EMPTY_ALPHA:
        raise ValueError(f"camera {cfg.camera}: the image shows nothing of the avatar (out of view); not written")
    return Still(r.rgb, width, height)


def _angles(camera: str) -> tuple[float, float]:
    try:
        az, el = (float(v) for v in camera.split(","))
    except ValueError:
        raise ValueError(f"camera: expected front, subject or AZ,EL in degrees, got {camera!r}") from None
    if not (math.isfinite(az) and math.isfinite(el)):
        raise ValueError(f"camera: AZ,EL must be finite degrees, got {camera!r}")
    return az, el
