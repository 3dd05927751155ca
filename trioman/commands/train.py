"""``trioman train SUBJECT --out RUN [--extra-frames DIR]``: train an avatar (standard-library imports at module level)."""

from __future__ import annotations

import argparse


# The run's own options (TrainConfig's fields) and online augmentation's (AugmentConfig's): declared once, on the
# configs' fields (trioman/options.py).
TRAIN_OPTIONS = ("preset", "iterations", "image_scale", "seed", "extra_frames", "extra_weight", "refine_poses")


def _configs():
    from trioman.toolkit.train.augment_config import AugmentConfig
    from trioman.toolkit.train.config import TrainConfig

    return TrainConfig, AugmentConfig


def flags() -> dict[str, str]:
    """The fields the library's errors name -> this command's flags."""
    from trioman.runtime.options import flags as option_flags

    return {"run": "--out", "resume": "--resume", "extend_iterations": "--extend-iterations", **option_flags(*_configs())}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from trioman.options import add_options

    train_config, augment_config = _configs()
    parser.add_argument("subject", help="subject folder (docs/formats.md)")
    parser.add_argument("--out", required=True, help="run folder: config, checkpoints, training log")
    add_options(parser, train_config, TRAIN_OPTIONS)
    aug = parser.add_argument_group("online augmentation (Generator -> Refiner -> Examiner during training; "
                                    "the defaults: the schedule measured best, docs/augmentation.md)")
    add_options(aug, augment_config)
    parser.add_argument("--resume", action="store_true",
                        help="continue the run in --out from its latest checkpoint (same subject, options and trioman "
                             "version as the run, else refused naming what differs)")
    parser.add_argument("--extend-iterations", type=int, default=None, metavar="N",
                        help="with --resume: continue the run to N iterations in total, more than it was started with "
                             "(the learning-rate schedule follows N; recorded in RUN/config.json)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from trioman.options import given
    from trioman.toolkit import lpips
    from trioman.toolkit.train.config import TrainConfig, preset
    from trioman.toolkit.train.loop import train

    overrides = given(TrainConfig, args, TRAIN_OPTIONS)
    name = overrides.pop("preset", TrainConfig.preset)
    if "extra_frames" in overrides:
        if not Path(overrides["extra_frames"]).is_dir():
            raise FileNotFoundError(f"extra_frames: subject folder not found: {overrides['extra_frames']}")
        overrides["extra_frames"] = str(Path(overrides["extra_frames"]).resolve())
    elif "extra_weight" in overrides:
        raise ValueError("extra_weight: needs `extra_frames`")
    augment = augment_config(args)
    if augment is not None:
        overrides["augment"] = augment
    cfg = preset(name, **overrides)
    model = lpips.load_lpips()  # a named folder without the weights is an error before any work
    run_dir = train(args.subject, args.out, cfg, resume=args.resume, progress=not args.quiet, lpips=model,
                    extend_iterations=args.extend_iterations)
    if model is None:  # said once the run has trained, never before an error about the inputs
        print(f"train: {lpips.NOT_FOUND_MESSAGE}")
    print(f"train: run {run_dir} (checkpoints in {Path(run_dir) / 'checkpoints'}, log {Path(run_dir) / 'train_log.csv'})")
    return 0


def augment_config(args: argparse.Namespace):
    """The AugmentConfig of --augment and its options (paths made absolute), or None without --augment."""
    from pathlib import Path

    from trioman.options import given
    from trioman.runtime.pretrained import NONE, SHIPPED
    from trioman.toolkit.train.augment_config import AugmentConfig

    values = given(AugmentConfig, args)
    if "mode" not in values:
        if values:
            raise ValueError(f"{next(iter(values))}: needs `mode`")
        return None
    for key in ("refiner", "examiner"):
        if key in values and values[key] not in (NONE, SHIPPED):
            if not Path(values[key]).exists():
                raise FileNotFoundError(f"{key}: not found: {values[key]}")
            values[key] = str(Path(values[key]).resolve())
    return AugmentConfig(**values)
