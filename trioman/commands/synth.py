"""``trioman synth``: render a synthetic subject (standard-library imports only at module level)."""

from __future__ import annotations

import argparse

# The parameters the library's errors name (runtime.image_io.check_folder_target) -> the flags as typed; trioman/cli.py
# shows the errors with them (trioman/commands/flags.py).
FLAGS = {"overwrite": "--overwrite"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", required=True, help="output subject folder")
    parser.add_argument("--seed", type=int, default=0, help="body shape, clothing and noise seed (default 0)")
    parser.add_argument("--size", type=int, default=256, help="image side in pixels (default 256)")
    parser.add_argument("--frames", type=int, default=120, help="total frames, training turn + test motions (default 120)")
    parser.add_argument("--test-fraction", type=float, default=0.2, help="fraction of frames in the test split (default 0.2)")
    parser.add_argument("--pose-noise", type=float, default=0.0, metavar="DEG",
                        help="std in degrees of the noise added to the stored poses, mimicking fitted parameters (default 0)")
    parser.add_argument("--coverage", type=float, default=1.0, metavar="FRACTION",
                        help="fraction of a full turn the training frames span, from facing the camera: 1 all round "
                             "(default), 0.5 half a turn, 0.2 front only (a capture seen from one side)")
    parser.add_argument("--overwrite", action="store_true", help="replace an existing subject folder")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    import time
    from pathlib import Path

    from trioman.toolkit.synth.subject import SynthConfig, synthesize_subject

    cfg = SynthConfig(seed=args.seed, size=args.size, frames=args.frames, test_fraction=args.test_fraction,
                      pose_noise_deg=args.pose_noise, coverage=args.coverage)
    start = time.perf_counter()
    subject = synthesize_subject(cfg, args.out, overwrite=args.overwrite, progress=not args.quiet)
    seconds = time.perf_counter() - start
    n_train, n_test = len(subject.indices("train")), len(subject.indices("test"))
    print(f"synth: wrote {subject.num_frames} frames ({n_train} train, {n_test} test) "
          f"at {cfg.size}x{cfg.size} to {subject.root} in {seconds:.1f} s")
    print(f"synth: contact sheet {Path(args.out) / 'contact_sheet.png'}")
    return 0
