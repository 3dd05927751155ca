"""``trioman train SUBJECT --out RUN [--extra-frames DIR]``: train an avatar (standard-library imports at module level)."""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("subject", help="subject folder (docs/formats.md)")
    parser.add_argument("--out", required=True, help="run folder: config, checkpoints, training log")
    parser.add_argument("--preset", default="quick", choices=("quick", "full"), help="training preset (default quick)")
    parser.add_argument("--iterations", type=int, default=None, help="override the preset's iteration count")
    parser.add_argument("--image-scale", type=float, default=None, help="train on images resized by this factor")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--extra-frames", default=None, metavar="DIR",
                        help="also train on this subject folder of pseudo-GT frames (trioman augment --out DIR)")
    parser.add_argument("--extra-weight", type=float, default=None,
                        help="loss weight of the --extra-frames frames (default 1)")
    parser.add_argument("--resume", action="store_true", help="continue the run in --out from its latest checkpoint")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from trioman.toolkit.train.config import preset
    from trioman.toolkit.train.loop import train

    overrides = {"seed": args.seed}
    if args.iterations is not None:
        overrides["iterations"] = args.iterations
    if args.image_scale is not None:
        overrides["image_scale"] = args.image_scale
    if args.extra_frames is not None:
        if not Path(args.extra_frames).is_dir():
            raise FileNotFoundError(f"--extra-frames: subject folder not found: {args.extra_frames}")
        overrides["extra_frames"] = str(Path(args.extra_frames).resolve())
    if args.extra_weight is not None:
        if args.extra_frames is None:
            raise ValueError("--extra-weight: needs --extra-frames")
        overrides["extra_weight"] = args.extra_weight
    cfg = preset(args.preset, **overrides)
    lpips = load_lpips_or_say_why("train")
    run_dir = train(args.subject, args.out, cfg, resume=args.resume, progress=not args.quiet, lpips=lpips)
    print(f"train: run {run_dir} (checkpoints in {Path(run_dir) / 'checkpoints'}, log {Path(run_dir) / 'train_log.csv'})")
    return 0


def load_lpips_or_say_why(command: str):
    """The LPIPS (AlexNet) model when its weights are available locally, else None after saying so once."""
    from trioman.toolkit.lpips import NOT_FOUND_MESSAGE, load_lpips

    model = load_lpips()
    if model is None:
        print(f"{command}: {NOT_FOUND_MESSAGE}")
    return model
