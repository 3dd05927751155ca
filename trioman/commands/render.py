"""``trioman render AVATAR --pose P --camera C --out img.png``: one image of an avatar, no torch
(runtime/still.py: what --pose and --camera take).

The library's errors name its parameters (``size: ...``, ``pose ...:``); trioman/cli.py shows them with ``flags()``.
Module contract (trioman/cli.py): standard-library imports only at module level.
"""

from __future__ import annotations

import argparse


def _configs():
    from trioman.runtime.animate import RenderOptions

    return (RenderOptions,)


def flags() -> dict[str, str]:
    """The fields the library's errors name -> this command's flags."""
    from trioman.runtime.options import flags as option_flags

    return {**option_flags(*_configs()), "avatar": "AVATAR", "pose": "--pose"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from trioman.options import add_options

    parser.add_argument("avatar", metavar="AVATAR", help="avatar folder (trioman export avatar)")
    parser.add_argument("--pose", default="rest", help="rest | MOTION[@FRAME] | SUBJECT@FRAME (default rest)")
    parser.add_argument("--out", required=True, help="output PNG path")
    add_options(parser, *_configs())


def run(args: argparse.Namespace) -> int:
    import time
    from pathlib import Path

    from trioman.options import given
    from trioman.runtime.formats import load_avatar
    from trioman.runtime.image_io import write_png
    from trioman.runtime.outputs import check_not_input
    from trioman.runtime.still import pose_source, render_still

    (options,) = _configs()
    cfg = options(**given(options, args))
    out = Path(args.out)
    if not out.parent.is_dir():
        raise FileNotFoundError(f"--out: the folder {out.parent} does not exist")
    source = pose_source(args.pose)
    try:  # the image never replaces or enters what the command reads: the avatar, the subject or motion of --pose
        check_not_input(out, [args.avatar, source])
    except ValueError as err:
        raise ValueError(f"--out {err}") from None
    avatar = load_avatar(args.avatar)
    t0 = time.perf_counter()
    still = render_still(avatar, args.pose, cfg)
    write_png(out, still.rgb)
    print(f"render: {out} ({still.width}x{still.height}, {avatar.num_gaussians} Gaussians, "
          f"{1000 * (time.perf_counter() - t0):.0f} ms)")
    return 0
