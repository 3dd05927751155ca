"""``trioman synth-corpus --out DIR``: synthetic subjects, baseline avatars and triplets for the
Refiner and Examiner (toolkit/corpus.py). Resumes where an interrupted build stopped."""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", required=True, help="corpus folder")
    parser.add_argument("--subjects", type=int, default=10, help="training subjects (default 10)")
    parser.add_argument("--heldout", type=int, default=2, help="held-out subjects (default 2)")
    parser.add_argument("--size", type=int, default=128, help="image side (default 128)")
    parser.add_argument("--frames", type=int, default=96, help="frames per subject (default 96)")
    parser.add_argument("--iterations", type=int, default=600, help="baseline training iterations (default 600)")
    parser.add_argument("--baseline-frames", choices=("all", "subset"), default="all",
                        help="what training subjects' baselines see: all frames (paper) or every 4th (default all)")
    parser.add_argument("--seed", type=int, default=1000, help="first subject seed (default 1000)")
    parser.add_argument("--quiet", action="store_true")


def run(args: argparse.Namespace) -> int:
    import time

    from trioman.toolkit.corpus import CorpusConfig, build_corpus

    cfg = CorpusConfig(train_subjects=args.subjects, heldout_subjects=args.heldout, size=args.size, frames=args.frames,
                       seed=args.seed, iterations=args.iterations, baseline_frames=args.baseline_frames)
    t = time.perf_counter()
    root = build_corpus(args.out, cfg, progress=not args.quiet)
    print(f"synth-corpus: {root} ({args.subjects} training + {args.heldout} held-out subjects) in {time.perf_counter() - t:.0f} s")
    return 0
