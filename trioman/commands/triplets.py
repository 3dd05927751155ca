"""``trioman triplets RUN --out FILE``: GT, coarse render and body normal map for every frame of a
trained run's subject (toolkit/triplets.py), the Refiner's and Examiner's training data."""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run", metavar="RUN", help="a trained avatar run folder (trioman train)")
    parser.add_argument("--out", required=True, help="output .npz")
    parser.add_argument("--quiet", action="store_true")


def run(args: argparse.Namespace) -> int:
    from trioman.toolkit.triplets import build_triplets

    print(f"triplets: {build_triplets(args.run, args.out, progress=not args.quiet)}")
    return 0
