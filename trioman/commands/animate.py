"""``trioman animate AVATAR --motion M --out out.mp4``: an avatar driven by a motion, as an MP4 (no torch).

The library: trioman.runtime.animate, whose errors name its parameters (``size: ...``); trioman/cli.py shows
them with ``FLAGS``. Module contract (trioman/cli.py): standard-library imports only at module level.
"""

from __future__ import annotations

import argparse

# The parameters the library's errors name -> the flags as typed (trioman/commands/flags.py).
FLAGS = {"avatar": "AVATAR", "motion": "--motion", "out": "--out", "azimuth": "--azimuth", "elevation": "--elevation",
         "size": "--size", "background": "--background"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("avatar", metavar="AVATAR", help="avatar folder (trioman export avatar)")
    parser.add_argument("--motion", required=True,
                        help="a shipped motion (walk, wave, squat, turn, jump, step, arms_raised), a motion .npz "
                             "file, or a subject folder (its test poses; SUBJECT:SEQUENCE for one sequence)")
    parser.add_argument("--out", required=True, help="output MP4 path")
    parser.add_argument("--camera", choices=("fixed", "orbit"), default="fixed", help="camera path (default fixed)")
    parser.add_argument("--azimuth", type=float, default=20.0, help="degrees; 0 = in front of the subject (default 20)")
    parser.add_argument("--elevation", type=float, default=5.0, help="degrees above the subject's centre (default 5)")
    parser.add_argument("--size", type=int, default=512, help="image side in pixels (default 512)")
    parser.add_argument("--frames", type=int, default=None, help="length of a shipped motion (default: its own)")
    parser.add_argument("--fps", type=float, default=None, help="video frame rate (default: the motion's)")
    parser.add_argument("--background", default="1,1,1", help="r,g,b in [0, 1] (default white)")
    parser.add_argument("--frames-dir", default=None, help="also write every frame as a PNG here")
    parser.add_argument("--no-pose-dependent", action="store_true", help="skip the avatar's pose-dependent deltas")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from trioman.runtime.animate import animate, check_angles, check_video_size, parse_background
    from trioman.runtime.formats import load_avatar
    from trioman.runtime.formats.motion import FPS_RANGE, MAX_FRAMES, motion_from_spec
    from trioman.runtime.image_io import check_not_input

    bg = parse_background(args.background)
    if args.frames is not None and not 1 <= args.frames <= MAX_FRAMES:
        raise ValueError(f"--frames: must lie in [1, {MAX_FRAMES}] (an hour at 30 fps), got {args.frames}")
    if args.fps is not None and not FPS_RANGE[0] <= args.fps <= FPS_RANGE[1]:
        raise ValueError(f"--fps: must lie in [{FPS_RANGE[0]}, {FPS_RANGE[1]}] frames per second, got {args.fps}")
    check_video_size(args.size)
    check_angles(azimuth=args.azimuth, elevation=args.elevation)
    inputs = [args.avatar] + ([args.motion] if Path(args.motion).exists() else [])  # else a built-in motion's name
    for flag, path in (("--out", args.out), ("--frames-dir", args.frames_dir or None)):
        if path is None:
            continue
        try:  # nothing written over or into what the command reads
            check_not_input(path, inputs)
        except ValueError as err:
            raise ValueError(f"{flag}: {err}") from None
    avatar = load_avatar(args.avatar)
    motion = motion_from_spec(args.motion, avatar.skeleton, args.frames)
    r = animate(avatar, motion, args.out, args.camera, args.azimuth, args.elevation, args.size, bg, args.fps,
                args.frames_dir, not args.no_pose_dependent, not args.quiet)
    print(f"animate: {r['frames']} frames of {motion.name!r} ({r['gaussians']} Gaussians, {r['size']}x{r['size']}) "
          f"in {r['seconds']:.1f} s: {r['ms_per_frame']:.1f} ms/frame (pose {r['pose_ms']:.1f}, render "
          f"{r['render_ms']:.1f}), {1000 / r['ms_per_frame']:.1f} fps")
    if r["empty"]:
        print(f"animate: warning: {len(r['empty'])} of {r['frames']} frames show nothing of the avatar (first: frame "
              f"{r['empty'][0]})")
    print(f"animate: video {r['video']}" + (f"; frames {args.frames_dir}" if args.frames_dir else ""))
    return 0
