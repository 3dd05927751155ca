"""``trioman synth-corpus --out DIR``: synthetic subjects, baseline avatars and triplets for the
Refiner and Examiner (toolkit/corpus.py). Resumes where an interrupted build stopped.

``--shard I/N`` builds only the subjects of shard I of N (N jobs, on one machine or many sharing DIR);
``--merge`` with the same settings then checks every shard and writes corpus.json (docs/scaling.md).
The library's errors name its parameters (``shard: ...``, ``merge: ...``); trioman/cli.py shows them with
``FLAGS`` (trioman/commands/flags.py)."""

from __future__ import annotations

import argparse

# The parameters the library's errors name (runtime/shards.py, toolkit/corpus.py) -> the flags as typed.
FLAGS = {"shard": "--shard", "merge": "--merge", "style": "--style"}


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
    parser.add_argument("--style", choices=("plain", "realistic"), default="plain",
                        help="the subjects' synth style (trioman synth --style; default plain)")
    parser.add_argument("--quiet", action="store_true")
    parser.add_argument("--shard", metavar="I/N", help="build only the subjects of shard I of N (0 <= I < N), no corpus.json")
    parser.add_argument("--merge", action="store_true",
                        help="after every --shard job: check them and write corpus.json (the same settings as the shards)")


def run(args: argparse.Namespace) -> int:
    import time

    from trioman.runtime.shards import Shard
    from trioman.toolkit.corpus import CorpusConfig, build_corpus, merge_corpus

    if args.shard is not None and args.merge:
        raise ValueError("--merge: runs after the --shard jobs, not with --shard")
    shard = None if args.shard is None else Shard.parse(args.shard)
    cfg = CorpusConfig(train_subjects=args.subjects, heldout_subjects=args.heldout, size=args.size, frames=args.frames,
                       seed=args.seed, iterations=args.iterations, baseline_frames=args.baseline_frames,
                       style=args.style)
    t = time.perf_counter()
    if args.merge:
        root = merge_corpus(args.out, cfg)
        print(f"synth-corpus: {root} merged ({args.subjects} training + {args.heldout} held-out subjects)")
        return 0
    root = build_corpus(args.out, cfg, progress=not args.quiet, shard=shard)
    what = f"{args.subjects} training + {args.heldout} held-out subjects"
    if shard is not None:
        what = f"shard {shard}: {len(shard.take(cfg.names))} of {what}; merge with --merge when every shard is done"
    print(f"synth-corpus: {root} ({what}) in {time.perf_counter() - t:.0f} s")
    return 0
