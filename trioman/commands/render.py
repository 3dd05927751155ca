"""``trioman render AVATAR --pose P --camera C --out img.png``: one image of an avatar, no torch.

--pose:   ``rest``; ``MOTION@I``, frame I of a shipped motion or a motion .npz (``@I`` optional, 0);
          ``SUBJECT@I``, frame I of a subject folder (its stored pose).
--camera: ``front`` (default), ``AZ,EL`` in degrees about the posed body (0,0 = in front, framed to
          fit), or ``subject`` (the camera of the subject frame given with --pose).

The library's errors name its parameters (``size: ...``); trioman/cli.py shows them with ``flags()``.
Module contract (trioman/cli.py): standard-library imports only at module level.
"""

from __future__ import annotations

import argparse
import math


def _configs():
    from trioman.runtime.animate import RenderOptions

    return (RenderOptions,)


def flags() -> dict[str, str]:
    """The fields the library's errors name -> this command's flags."""
    from trioman.runtime.options import flags as option_flags

    return {**option_flags(*_configs()), "avatar": "AVATAR"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from trioman.options import add_options

    parser.add_argument("avatar", metavar="AVATAR", help="avatar folder (trioman export avatar)")
    parser.add_argument("--pose", default="rest", help="rest | MOTION[@FRAME] | SUBJECT@FRAME (default rest)")
    parser.add_argument("--out", required=True, help="output PNG path")
    add_options(parser, *_configs())


def _split_frame(spec: str) -> tuple[str, int]:
    source, sep, frame = spec.rpartition("@")
    if not sep:
        return spec, 0
    try:
        return source, int(frame)
    except ValueError:
        raise ValueError(f"--pose: frame after '@' must be an integer, got {frame!r} in {spec!r}") from None


def resolve_pose(spec: str, skeleton):
    """-> (pose [J, 3], trans [3], subject camera (K, viewmat, width, height) or None)."""
    from pathlib import Path

    import numpy as np

    from trioman.runtime.formats import load_subject
    from trioman.runtime.formats.motion import motion_from_spec
    from trioman.runtime.motions import Motion

    if spec == "rest":
        return np.zeros((skeleton.num_joints, 3)), np.zeros(3), None
    source, i = _split_frame(spec)
    if Path(source).is_dir():
        subject = load_subject(source, check_images=False)
        if not 0 <= i < subject.num_frames:
            raise ValueError(f"--pose: frame {i} is out of range for {source} ({subject.num_frames} frames)")
        frames = Motion(source, np.array(subject.poses), np.array(subject.trans),
                        subject.body.skeleton.joint_names).for_skeleton(skeleton)  # joints matched by name
        cam = (np.array(subject.K[i]), np.array(subject.viewmat[i]), subject.width, subject.height)
        return frames.pose[i], frames.trans[i], cam
    motion = motion_from_spec(source, skeleton)
    if not 0 <= i < motion.num_frames:
        raise ValueError(f"--pose: frame {i} is out of range for {source!r} ({motion.num_frames} frames)")
    return motion.pose[i], motion.trans[i], None


def run(args: argparse.Namespace) -> int:
    import time
    from pathlib import Path

    import numpy as np

    from trioman.options import given
    from trioman.runtime.animate import EMPTY_ALPHA, parse_background
    from trioman.runtime.cameras import frame_points
    from trioman.runtime.formats import load_avatar
    from trioman.runtime.image_io import write_png
    from trioman.runtime.outputs import check_not_input
    from trioman.runtime.render import rasterize

    (options,) = _configs()
    cfg = options(**given(options, args))
    out = Path(args.out)
    if not out.parent.is_dir():
        raise FileNotFoundError(f"--out: the folder {out.parent} does not exist")
    pose_source = None if args.pose == "rest" else _split_frame(args.pose)[0]
    try:  # the image never replaces or enters what the command reads: the avatar, the subject or motion of --pose
        check_not_input(out, [args.avatar, pose_source])
    except ValueError as err:
        raise ValueError(f"--out {err}") from None
    avatar = load_avatar(args.avatar)
    pose, trans, subject_cam = resolve_pose(args.pose, avatar.skeleton)
    t0 = time.perf_counter()
    g = avatar.gaussians(pose, trans, pose_dependent=cfg.pose_dependent)
    if cfg.camera == "subject":
        if subject_cam is None:
            raise ValueError("--camera: 'subject' needs --pose SUBJECT@FRAME (the camera comes from that frame)")
        K, viewmat, width, height = subject_cam
        if cfg.size is not None:  # keep the view, change the resolution
            s = cfg.size / max(width, height)
            K = K.copy()
            K[:2] *= s
            width, height = round(width * s), round(height * s)
    else:
        if cfg.camera == "front":
            az, el = 0.0, 5.0
        else:
            try:
                az, el = (float(v) for v in cfg.camera.split(","))
            except ValueError:
                raise ValueError(f"--camera: expected front, subject or AZ,EL in degrees, got {cfg.camera!r}") from None
            if not (math.isfinite(az) and math.isfinite(el)):
                raise ValueError(f"--camera: AZ,EL must be finite degrees, got {cfg.camera!r}")
        width = height = cfg.size or 512
        try:
            K, viewmat, _ = frame_points(g.means, (width, height), np.deg2rad(az), np.deg2rad(el))
        except ValueError as err:
            raise ValueError(f"--pose {args.pose}: the avatar cannot be framed: {err}") from None
    r = rasterize(*g, viewmat, K, width, height, background=parse_background(cfg.background))
    if not r.alpha.max() >= EMPTY_ALPHA:
        raise ValueError(f"--camera {cfg.camera}: the image shows nothing of the avatar (out of view); not written")
    write_png(out, r.rgb)
    print(f"render: {out} ({width}x{height}, {avatar.num_gaussians} Gaussians, {1000 * (time.perf_counter() - t0):.0f} ms)")
    return 0
