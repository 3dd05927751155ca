"""``trioman synth-corpus --out DIR``: synthetic subjects, baseline avatars and triplets for the
Refiner and Examiner (toolkit/corpus/build.py). Resumes where an interrupted build stopped.

``--shard I/N`` builds only the subjects of shard I of N (N jobs, on one machine or many sharing DIR);
``--merge`` with the same settings then checks every shard and writes corpus.json (docs/scaling.md).
The library's errors name its parameters (``shard: ...``, ``merge: ...``); trioman/cli.py shows them with
``flags()`` (trioman/commands/flags.py)."""

from __future__ import annotations

import argparse

def _configs():
    from trioman.toolkit.corpus.config import CorpusConfig

    return (CorpusConfig,)


def flags() -> dict[str, str]:
    """The fields the library's errors name -> this command's flags."""
    from trioman.runtime.options import flags as option_flags

    return {"shard": "--shard", "merge": "--merge", **option_flags(*_configs())}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from trioman.options import add_options

    parser.add_argument("--out", required=True, help="corpus folder")
    add_options(parser, *_configs())
    parser.add_argument("--quiet", action="store_true", help="no progress bars")
    parser.add_argument("--shard", metavar="I/N", help="build only the subjects of shard I of N (0 <= I < N), no corpus.json")
    parser.add_argument("--merge", action="store_true",
                        help="after every --shard job: check them and write corpus.json (the same settings as the shards)")


def run(args: argparse.Namespace) -> int:
    import time

    from trioman.options import given
    from trioman.runtime.shards import Shard
    from trioman.toolkit.corpus.build import build_corpus, merge_corpus

    if args.shard is not None and args.merge:
        raise ValueError("--merge: runs after the --shard jobs, not with --shard")
    shard = None if args.shard is None else Shard.parse(args.shard)
    (corpus_config,) = _configs()
    cfg = corpus_config(**given(corpus_config, args))
    t = time.perf_counter()
    if args.merge:
        root = merge_corpus(args.out, cfg)
        print(f"synth-corpus: {root} merged ({cfg.train_subjects} training + {cfg.heldout_subjects} held-out subjects)")
        return 0
    root = build_corpus(args.out, cfg, progress=not args.quiet, shard=shard)
    what = f"{cfg.train_subjects} training + {cfg.heldout_subjects} held-out subjects"
    if shard is not None:
        what = f"shard {shard}: {len(shard.take(cfg.names))} of {what}; merge with --merge when every shard is done"
    print(f"synth-corpus: {root} ({what}) in {time.perf_counter() - t:.0f} s")
    return 0
