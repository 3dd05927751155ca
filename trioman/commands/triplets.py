"""``trioman triplets RUN --out FILE``: GT, coarse render, body normal map and aligned reference for every
frame of a trained run's subject (toolkit/triplets.py), the Refiner's and Examiner's training data; with
``--draws N`` (synthetic subjects) N Generator draws per training frame with the truth there instead."""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run", metavar="RUN", help="a trained avatar run folder (trioman train)")
    parser.add_argument("--out", required=True, help="output .npz")
    parser.add_argument("--draws", type=int, metavar="N",
                        help="synthetic subjects: N Generator draws per training frame, the truth at each as GT "
                             "(what a Refiner meets during augmentation) instead of the subject's frames")
    parser.add_argument("--seed", type=int, default=0, help="the draws' seed (default 0)")
    parser.add_argument("--quiet", action="store_true")


def run(args: argparse.Namespace) -> int:
    from trioman.toolkit.triplets import build_draw_triplets, build_triplets

    if args.draws is not None and args.draws < 1:
        raise ValueError(f"--draws: must be >= 1, got {args.draws}")
    if args.draws is None:
        out = build_triplets(args.run, args.out, progress=not args.quiet)
    else:
        out = build_draw_triplets(args.run, args.out, args.draws, args.seed, progress=not args.quiet)
    print(f"triplets: {out}")
    return 0
