"""``trioman demo``: the whole pipeline on the embedded synthetic subject (trioman.bench.demo).

Module contract (trioman/cli.py): standard-library imports only at module level.
"""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", default="out/demo", help="output folder (default out/demo)")
    parser.add_argument("--seed", type=int, default=0, help="subject seed (default 0)")
    parser.add_argument("--size", type=int, default=256, help="image side in pixels (default 256)")
    parser.add_argument("--frames", type=int, default=120, help="subject frames (default 120)")
    parser.add_argument("--iterations", type=int, default=500,
                        help="training iterations of both avatars, quick preset otherwise (default 500)")
    parser.add_argument("--model-steps", type=int, default=200, help="Refiner and Examiner training steps (default 200)")
    parser.add_argument("--augment-frames", type=int, default=24, help="source frames to augment (default 24)")
    parser.add_argument("--quiet", action="store_true", help="no progress bars")


def run(args: argparse.Namespace) -> int:
    from trioman.bench.demo import DemoConfig, run_demo

    run_demo(DemoConfig(out=args.out, seed=args.seed, size=args.size, frames=args.frames, iterations=args.iterations,
                        model_steps=args.model_steps, augment_frames=args.augment_frames, progress=not args.quiet))
    return 0
