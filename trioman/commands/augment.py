"""``trioman augment SUBJECT --avatar A [--refiner R.onnx|none [--examiner E.onnx|none]] --out DIR``: pseudo-GT
frames, no torch.

Generator -> coarse render -> aligned reference -> body normal map -> Refiner -> Examiner (keep the better of
the candidates, drop it below --threshold), per source frame; with a Refiner (--refiner shipped: the package's, runtime/pretrained.py, or
a file) the Examiner defaults to the shipped one; without one (--refiner none, the default) the aligned pseudo-GT
(no model); see trioman.runtime.augment and
docs/formats.md "Augmented frames". Train on the result with ``trioman train SUBJECT --extra-frames DIR``.

``--shard I/N`` does only shard I of N's source frames (in DIR/shards/I-of-N; N jobs on one machine or
many sharing DIR); ``--merge`` with the same inputs then checks every shard and assembles DIR
(docs/scaling.md).

The library's errors name its parameters (``per_frame: ...``); trioman/cli.py shows them with this command's flags
(``flags()``: ``--per-frame: ...``, docs/design.md, "Errors name what the caller gave").

Module contract (trioman/cli.py): standard-library imports only at module level.
"""

from __future__ import annotations

import argparse


def _configs():
    from trioman.runtime.augment_options import AugmentOptions

    return (AugmentOptions,)


def flags() -> dict[str, str]:
    """The parameters of trioman.runtime.augment.augment that this command's flags set -> the flag as typed."""
    from trioman.runtime.options import flags as option_flags

    return {**option_flags(*_configs()), "subject": "SUBJECT", "avatar": "--avatar", "refiner": "--refiner",
            "examiner": "--examiner", "out": "--out", "resume": "--resume", "overwrite": "--overwrite", "shard": "--shard",
            "merge": "--merge"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from trioman.options import add_options
    from trioman.runtime.pretrained import NONE, SHIPPED

    parser.add_argument("subject", metavar="SUBJECT", help="subject folder (docs/formats.md)")
    parser.add_argument("--avatar", required=True, help="avatar folder of this subject (trioman export avatar)")
    parser.add_argument("--refiner", default=NONE, metavar="ONNX|shipped|none",
                        help="Refiner ONNX file; shipped: the package's (docs/models.md); none: the aligned pseudo-GT, "
                             "the render with real pixels carried through the body mesh, and per-pixel loss weights "
                             "in DIR/weights, no model: the best kind measured with what ships (default none)")
    parser.add_argument("--examiner", default=SHIPPED, metavar="ONNX|shipped|none",
                        help="Examiner ONNX file; shipped: the package's (with a Refiner); none: every candidate is "
                             "kept (one frame per candidate) (default shipped)")
    parser.add_argument("--out", required=True, help="output folder: a subject of pseudo-GT frames + records")
    add_options(parser, *_configs())
    parser.add_argument("--resume", action="store_true", help="continue an interrupted run in --out (skips finished frames)")
    parser.add_argument("--overwrite", action="store_true", help="replace an earlier augment output in --out")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    parser.add_argument("--shard", metavar="I/N", help="do only the source frames of shard I of N (0 <= I < N)")
    parser.add_argument("--merge", action="store_true",
                        help="after every --shard job: check them and assemble --out (the same inputs as the shards)")


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from dataclasses import asdict

    from trioman.options import given
    from trioman.runtime.augment import AUGMENT_JSON, RECORDS_DIR, augment
    from trioman.runtime.shards import Shard

    shard = None if args.shard is None else Shard.parse(args.shard)
    (options,) = _configs()
    cfg = options(**given(options, args))
    r = augment(args.subject, args.avatar, args.refiner, args.out, args.examiner, **asdict(cfg), resume=args.resume,
                overwrite=args.overwrite, progress=not args.quiet, shard=shard, merge=args.merge)
    if shard is not None:
        print(f"augment: shard {shard} done ({len(r['items'])} source frames in {Path(args.out) / 'shards' / shard.name}); "
              f"assemble with --merge when every shard is done")
        return 0
    s, t = r["summary"], r["timing"]
    thr = "" if cfg.threshold is None else f" (threshold {cfg.threshold:g})"
    settings = r["settings"]
    if settings["examiner"] is None:
        how = "no --examiner" if settings["refiner"] else "no --refiner: aligned pseudo-GT with per-pixel weights"
        print(f"augment: {s['source_frames']} source frames, {s['candidates']} candidates, all kept ({how})")
    else:
        sc = s["chosen_scores"]
        print(f"augment: {s['source_frames']} source frames, {s['candidates']} candidates: {s['accepted']} accepted, "
              f"{s['rejected']} rejected{thr}; chosen scores mean {sc['mean']:.3f} [{sc['min']:.3f}, {sc['max']:.3f}]")
    ms = t["ms_per_source_frame"]
    print("augment: ms per source frame: " + ", ".join(f"{k} {v:.1f}" for k, v in ms.items())
          + (f" ({t['frames_resumed']} frames resumed)" if t["frames_resumed"] else ""))
    out = Path(args.out)
    if s["subject_written"]:
        print(f"augment: pseudo-GT subject {out} ({s['frames_written']} frames); "
              f"train with: trioman train {args.subject} --extra-frames {out} --out RUN")
    else:
        print(f"augment: {s['note']}")
    print(f"augment: records {out / RECORDS_DIR}, report {out / AUGMENT_JSON}"
          + (f", score histogram {out / s['histogram']}" if s["histogram"] else ""))
    return 0

