"""``trioman synth``: render a synthetic subject (standard-library imports only at module level)."""

from __future__ import annotations

import argparse

def _configs():
    from trioman.toolkit.synth.config import SynthConfig

    return (SynthConfig,)


def flags() -> dict[str, str]:
    """The fields the library's errors name -> this command's flags."""
    from trioman.runtime.options import flags as option_flags

    return {"overwrite": "--overwrite", "video": "--video", "out": "--out", **option_flags(*_configs())}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from trioman.options import add_options

    parser.add_argument("--out", required=True, help="output subject folder")
    add_options(parser, *_configs())
    parser.add_argument("--video", metavar="FILE.mp4",
                        help="also write the training frames as the video a user would have (background, sensor and all; "
                             "video frame k is the subject's frame k), outside the subject folder")
    parser.add_argument("--overwrite", action="store_true", help="replace an existing subject folder")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    import time
    from pathlib import Path

    from trioman.options import given
    from trioman.toolkit.synth.config import SynthConfig
    from trioman.toolkit.synth.subject import synthesize_subject

    cfg = SynthConfig(**given(SynthConfig, args))
    start = time.perf_counter()
    subject = synthesize_subject(cfg, args.out, overwrite=args.overwrite, progress=not args.quiet, video=args.video)
    seconds = time.perf_counter() - start
    n_train, n_test = len(subject.indices("train")), len(subject.indices("test"))
    print(f"synth: wrote {subject.num_frames} frames ({n_train} train, {n_test} test) "
          f"at {cfg.width}x{cfg.height} ({cfg.style}) to {subject.root} in {seconds:.1f} s")
    print(f"synth: contact sheet {Path(args.out) / 'contact_sheet.png'}")
    if args.video:
        print(f"synth: video {args.video} ({n_train} training frames at 30 fps)")
    return 0
