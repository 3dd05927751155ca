"""``trioman animate AVATAR --motion M --out out.mp4``: an avatar driven by a motion, as an MP4 (no torch).

The library: trioman.runtime.animate, whose errors name its parameters (``size: ...``); trioman/cli.py shows
them with ``flags()``. Module contract (trioman/cli.py): standard-library imports only at module level.
"""

from __future__ import annotations

import argparse


def _configs():
    from trioman.runtime.animate import AnimateOptions

    return (AnimateOptions,)


def flags() -> dict[str, str]:
    """The fields the library's errors name -> this command's flags."""
    from trioman.runtime.options import flags as option_flags

    return {**option_flags(*_configs()), "avatar": "AVATAR", "motion": "--motion", "out": "--out"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from trioman.options import add_options

    parser.add_argument("avatar", metavar="AVATAR", help="avatar folder (trioman export avatar)")
    parser.add_argument("--motion", required=True,
                        help="a shipped motion (walk, wave, squat, turn, jump, step, arms_raised), a motion .npz "
                             "file, or a subject folder (its test poses; SUBJECT:SEQUENCE for one sequence)")
    parser.add_argument("--out", required=True, help="output MP4 path")
    add_options(parser, *_configs())
    parser.add_argument("--frames-dir", default=None, help="also write every frame as a PNG here")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from trioman.options import given
    from trioman.runtime.animate import animate
    from trioman.runtime.formats import load_avatar
    from trioman.runtime.formats.motion import motion_from_spec
    from trioman.runtime.outputs import check_not_input

    (options,) = _configs()
    cfg = options(**given(options, args))
    inputs = [args.avatar] + ([args.motion] if Path(args.motion).exists() else [])  # else a built-in motion's name
    for flag, path in (("--out", args.out), ("--frames-dir", args.frames_dir or None)):
        if path is None:
            continue
        try:  # nothing written over or into what the command reads
            check_not_input(path, inputs)
        except ValueError as err:
            raise ValueError(f"{flag}: {err}") from None
    avatar = load_avatar(args.avatar)
    motion = motion_from_spec(args.motion, avatar.skeleton, cfg.frames)
    r = animate(avatar, motion, args.out, cfg.camera, cfg.azimuth, cfg.elevation, cfg.size, cfg.background, cfg.fps,
                args.frames_dir, cfg.pose_dependent, not args.quiet)
    print(f"animate: {r['frames']} frames of {motion.name!r} ({r['gaussians']} Gaussians, {r['size']}x{r['size']}) "
          f"in {r['seconds']:.1f} s: {r['ms_per_frame']:.1f} ms/frame (pose {r['pose_ms']:.1f}, render "
          f"{r['render_ms']:.1f}), {1000 / r['ms_per_frame']:.1f} fps")
    if r["empty"]:
        print(f"animate: warning: {len(r['empty'])} of {r['frames']} frames show nothing of the avatar (first: frame "
              f"{r['empty'][0]})")
    print(f"animate: video {r['video']}" + (f"; frames {args.frames_dir}" if args.frames_dir else ""))
    return 0
