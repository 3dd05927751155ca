"""``trioman triplets RUN --out FILE``: GT, coarse render, body normal map and aligned reference for every
frame of a trained run's subject (toolkit/corpus/triplets.py), the Refiner's and Examiner's training data; with
``--draws N`` (synthetic subjects) N Generator draws per training frame with the truth there instead."""

from __future__ import annotations

import argparse


def _configs():
    from trioman.toolkit.corpus.triplets_config import TripletsOptions

    return (TripletsOptions,)


def flags() -> dict[str, str]:
    """The fields the library's errors name -> this command's flags."""
    from trioman.runtime.options import flags as option_flags

    return {**option_flags(*_configs()), "out": "--out"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from trioman.options import add_options

    parser.add_argument("run", metavar="RUN", help="a trained avatar run folder (trioman train)")
    parser.add_argument("--out", required=True, help="output .npz")
    add_options(parser, *_configs())
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    from trioman.options import given
    from trioman.toolkit.corpus.triplets import build_draw_triplets, build_triplets

    (options,) = _configs()
    cfg = options(**given(options, args))
    if cfg.draws is None:
        out = build_triplets(args.run, args.out, progress=not args.quiet)
    else:
        out = build_draw_triplets(args.run, args.out, cfg.draws, cfg.seed, progress=not args.quiet)
    print(f"triplets: {out}")
    return 0
