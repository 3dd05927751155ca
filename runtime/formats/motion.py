"""The motion format (version 1): one .npz file of plain arrays (docs/formats.md).

    format       0-d str   "trioman-motion"
    version      0-d int   1
    name         0-d str   the motion's name
    fps          0-d float frames per second (in FPS_RANGE)
    joint_names  [J] str   the joints of ``poses``, matched by name to an avatar's skeleton
    poses        [T, J, 3] float32 axis-angle per joint (radians, world-aligned axes, see skeleton.py)
    trans        [T, 3]    float32 root translation (metres)

``load_motion`` raises FormatError naming the file and field; ``save_motion`` writes atomically.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from trioman.runtime.formats.common import FormatError, format_error, load_npz
from trioman.runtime.outputs import atomic_path
from trioman.runtime.motions import DEFAULT_FPS, DEFAULT_FRAMES, MOTIONS, Motion
from trioman.runtime.skeleton import Skeleton

MOTION_FORMAT = "trioman-motion"
MOTION_VERSION = 1
FPS_RANGE = (0.1, 1000.0)  # frames per second a video codec takes
MAX_FRAMES = 108_000  # a motion's longest length (an hour at 30 fps)
MAX_ARRAY_BYTES = MAX_FRAMES * 256 * 3 * 8  # the most a motion file's array may take once decompressed
_FIELDS = ("format", "version", "name", "fps", "joint_names", "poses", "trans")
MAX_ANGLE = 1e3  # radians: a larger axis-angle is no joint rotation (float32 sin/cos lose it)
MAX_TRANS = 1e4  # metres from the origin


def _scalar(arrays: dict, key: str, kind: str, where: Path):
    a = arrays[key]
    if a.shape != () or a.dtype.kind not in kind:
        raise format_error(where, key, f"expected a scalar of kind {kind!r}, got dtype {a.dtype} shape {list(a.shape)}")
    return a.item()


def load_motion(path: str | os.PathLike) -> Motion:
    """Load and validate a motion file. -> Motion with joint_names and fps set."""
    path = Path(path)
    arrays = load_npz(path, max_bytes=MAX_ARRAY_BYTES)
    for key in _FIELDS:
        if key not in arrays:
            raise format_error(path, key, "missing array")
    fmt = _scalar(arrays, "format", "U", path)
    if fmt != MOTION_FORMAT:
        raise format_error(path, "format", f"expected {MOTION_FORMAT!r}, got {fmt!r}: not a TrioMan motion")
    version = _scalar(arrays, "version", "iu", path)
    if version != MOTION_VERSION:
        raise format_error(path, "version", f"unknown version {version} (this trioman reads version {MOTION_VERSION})")
    name = _scalar(arrays, "name", "U", path)
    fps = float(_scalar(arrays, "fps", "fiu", path))
    if not (np.isfinite(fps) and FPS_RANGE[0] <= fps <= FPS_RANGE[1]):
        raise format_error(path, "fps", f"must lie in [{FPS_RANGE[0]}, {FPS_RANGE[1]}] frames per second, got {fps}")
    names = arrays["joint_names"]
    if names.ndim != 1 or names.dtype.kind != "U" or len(names) == 0:
        raise format_error(path, "joint_names", f"expected a non-empty 1-D str array, got dtype {names.dtype} shape {list(names.shape)}")
    if len(set(names.tolist())) != len(names):
        raise format_error(path, "joint_names", "names must be unique")
    J = len(names)
    poses, trans = arrays["poses"], arrays["trans"]
    if poses.dtype.kind != "f" or poses.ndim != 3 or poses.shape[1:] != (J, 3) or not 1 <= len(poses) <= MAX_FRAMES:
        raise format_error(path, "poses", f"expected float [T in [1, {MAX_FRAMES}], {J}, 3], got dtype {poses.dtype} shape {list(poses.shape)}")
    if trans.dtype.kind != "f" or trans.shape != (len(poses), 3):
        raise format_error(path, "trans", f"expected float [{len(poses)}, 3] (one per pose), got dtype {trans.dtype} shape {list(trans.shape)}")
    for key, a in (("poses", poses), ("trans", trans)):
        bad = int((~np.isfinite(a)).sum())
        if bad:
            raise format_error(path, key, f"{bad} value(s) are NaN or Inf")
    size = {"poses": np.linalg.norm(poses.astype(np.float64), axis=-1), "trans": np.abs(trans.astype(np.float64)).max(-1)}
    for key, limit, what in (("poses", MAX_ANGLE, "a rotation angle of"), ("trans", MAX_TRANS, "a translation of")):
        if size[key].max() > limit:
            at = np.unravel_index(np.argmax(size[key]), size[key].shape)
            where = f"frame {at[0]}" + (f", joint {str(names[at[1]])!r}" if key == "poses" else "")
            raise format_error(path, key, f"{where}: {what} {float(size[key][at]):.3g} ({'rad' if key == 'poses' else 'm'}), "
                                   f"beyond {limit:g}")
    return Motion(name, poses.astype(np.float32), trans.astype(np.float32), tuple(names.tolist()), fps)


def save_motion(path: str | os.PathLike, motion: Motion) -> Path:
    """Write ``motion`` (its joint_names must be set) atomically as a .npz motion file. -> the path."""
    path = Path(path)
    if motion.joint_names is None:
        raise FormatError(f"save_motion: joint_names: motion {motion.name!r} names no joints")
    arrays = {
        "format": np.array(MOTION_FORMAT), "version": np.array(MOTION_VERSION), "name": np.array(motion.name),
        "fps": np.array(float(motion.fps)), "joint_names": np.array(motion.joint_names, dtype=np.str_),
        "poses": np.asarray(motion.pose, dtype=np.float32), "trans": np.asarray(motion.trans, dtype=np.float32),
    }
    with atomic_path(path, suffix=".npz") as tmp:
        with open(tmp, "wb") as f:
            np.savez(f, **arrays)
    load_motion(path)  # what was written reads back
    return path


def motion_from_subject(path: str | os.PathLike, split: str = "test", sequence: str | None = None) -> Motion:
    """A subject's stored poses as a motion: the frames of ``split`` (and of one ``sequence`` if given),
    in file order, with the subject's joint names."""
    from trioman.runtime.formats.subject import load_subject

    subject = load_subject(path, check_images=False)
    keep = subject.split == split
    if sequence is not None:
        if sequence not in set(subject.sequence.tolist()):
            raise FormatError(f"{path}: sequence: no sequence {sequence!r} (have {sorted(set(subject.sequence.tolist()))})")
        keep &= subject.sequence == sequence
    if not keep.any():
        raise FormatError(f"{path}: split: no {split!r} frames" + (f" in sequence {sequence!r}" if sequence else ""))
    name = f"{Path(path).name}:{sequence or split}"
    return Motion(name, np.array(subject.poses[keep]), np.array(subject.trans[keep]),
                  subject.body.skeleton.joint_names, float(subject.meta.get("fps", DEFAULT_FPS)))


def motion_from_spec(spec: str, skeleton: Skeleton, frames: int | None = None) -> Motion:
    """Resolve ``trioman animate --motion SPEC`` for ``skeleton``: a shipped motion name (MOTIONS), a
    motion .npz file, or a subject folder (its test poses; ``SUBJECT:SEQUENCE`` for one sequence).
    ``frames`` sets a shipped motion's length. -> the motion in the skeleton's joint order."""
    if frames is not None and not 1 <= frames <= MAX_FRAMES:
        raise ValueError(f"frames: must lie in [1, {MAX_FRAMES}] (an hour at 30 fps), got {frames}")
    if spec in MOTIONS:
        n = frames if frames is not None else DEFAULT_FRAMES[spec]
        return MOTIONS[spec](skeleton, n).for_skeleton(skeleton)
    path, _, sequence = spec.partition(":") if not Path(spec).exists() else (spec, "", "")
    p = Path(path)
    if p.is_dir():
        motion = motion_from_subject(p, "test", sequence or None)
    elif p.is_file():
        motion = load_motion(p)
    else:
        raise FileNotFoundError(f"motion: {spec!r} is neither a shipped motion ({', '.join(MOTIONS)}), "
                                f"a motion file nor a subject folder")
    return motion.for_skeleton(skeleton)
