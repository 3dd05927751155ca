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
    parser.add_argument("--refine-poses", action="store_true",
                        help="learn corrections of the subject's poses with the avatar (poses fitted to a video, "
                             "trioman fit): the held-out frames take the corrections of the frames around them")
    aug = parser.add_argument_group("online augmentation (Generator -> Refiner -> Examiner during training)")
    aug.add_argument("--augment", choices=("coarse", "aligned", "refined", "examined", "truth", "truth_seen"), default=None,
                     nargs="?", const="aligned",
                     help="pseudo-GT frames made during training (--augment alone: aligned, the best kind without a "
                          "model; refined by a warp+geo --refiner measured better, docs/augmentation.md): the avatar's own renders at Generator poses and "
                          "cameras (coarse), with real pixels carried through the body mesh where known (aligned), "
                          "refined by --refiner (refined), the best of --per-frame refined candidates by --examiner "
                          "(examined), or the subject's own renderer (truth: synthetic subjects only, the ceiling; truth_seen: the same only where "
                          "a training frame saw the surface)")
    aug.add_argument("--refiner", default=None, metavar="RUN|CKPT|ONNX", help="Refiner: train-refiner run, checkpoint or .onnx")
    aug.add_argument("--examiner", default=None, metavar="RUN|CKPT|ONNX", help="Examiner: train-examiner run, checkpoint or .onnx")
    aug.add_argument("--per-frame", type=int, default=None, help="Generator candidates per source frame (default 2 with an Examiner, else 1)")
    aug.add_argument("--threshold", type=float, default=None, help="drop the Examiner's best candidate below this score")
    aug.add_argument("--augment-start", type=float, default=None, help="fraction of iterations on real frames only first (default 0.4)")
    aug.add_argument("--augment-refresh", type=int, default=None, help="steps between rebuilds of the pseudo-GT pool (default 100)")
    aug.add_argument("--augment-pool", type=int, default=None, help="pseudo-GT frames per rebuild (default 8)")
    aug.add_argument("--augment-share", type=float, default=None, help="share of steps after the warm-up on pseudo-GT frames (default 0.5)")
    aug.add_argument("--augment-weight", type=float, default=None, help="loss weight of a pseudo-GT frame (default 1)")
    aug.add_argument("--augment-detail-sigma", type=float, default=None, metavar="PX",
                     help="keep only the Refiner's detail: its change minus that change blurred by PX pixels, so the "
                          "avatar does not learn the Refiner's colour shift (default 0: the refined frame as it is)")
    aug.add_argument("--augment-mask", choices=("carried", "alpha"), default=None,
                     help="a pseudo frame's mask: the body mesh plus the source frame's mask carried to the draw "
                          "(carried, default) or the avatar render's own alpha (alpha, the paper's)")
    aug.add_argument("--augment-unknown-weight", type=float, default=None,
                     help="--augment aligned|truth_seen: loss weight of body pixels no real pixel reached (default 0)")
    aug.add_argument("--augment-keep-carried", action=argparse.BooleanOptionalAction, default=None,
                     help="--augment refined|examined: keep the real pixels carried to the draw and take the "
                          "Refiner's output only where nothing was carried (default with those kinds; measured best, "
                          "docs/augmentation.md)")
    aug.add_argument("--augment-sources", type=int, default=None,
                     help="training frames the aligned reference fuses per draw (default 3)")
    aug.add_argument("--augment-texture", type=int, default=None, metavar="TEXELS",
                     help="take the aligned reference's colour from a texture of this side fused from every training "
                          "frame wherever its texels were seen (runtime/texture_fusion.py; default 0: carried pixels only)")
    parser.add_argument("--resume", action="store_true",
                        help="continue the run in --out from its latest checkpoint (same subject, options and trioman "
                             "version as the run, else refused naming what differs)")
    parser.add_argument("--extend-iterations", type=int, default=None, metavar="N",
                        help="with --resume: continue the run to N iterations in total, more than it was started with "
                             "(the learning-rate schedule follows N; recorded in RUN/config.json)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from trioman.toolkit import lpips
    from trioman.toolkit.train.config import preset
    from trioman.toolkit.train.loop import train

    overrides = {"seed": args.seed}
    if args.iterations is not None:
        overrides["iterations"] = args.iterations
    if args.image_scale is not None:
        overrides["image_scale"] = args.image_scale
    if args.refine_poses:
        overrides["refine_poses"] = True
    if args.extra_frames is not None:
        if not Path(args.extra_frames).is_dir():
            raise FileNotFoundError(f"--extra-frames: subject folder not found: {args.extra_frames}")
        overrides["extra_frames"] = str(Path(args.extra_frames).resolve())
    if args.extra_weight is not None:
        if args.extra_frames is None:
            raise ValueError("--extra-weight: needs --extra-frames")
        overrides["extra_weight"] = args.extra_weight
    augment = augment_config(args)
    if augment is not None:
        overrides["augment"] = augment
    cfg = preset(args.preset, **overrides)
    model = lpips.load_lpips()  # a named folder without the weights is an error before any work
    run_dir = train(args.subject, args.out, cfg, resume=args.resume, progress=not args.quiet, lpips=model,
                    extend_iterations=args.extend_iterations)
    if model is None:  # said once the run has trained, never before an error about the inputs
        print(f"train: {lpips.NOT_FOUND_MESSAGE}")
    print(f"train: run {run_dir} (checkpoints in {Path(run_dir) / 'checkpoints'}, log {Path(run_dir) / 'train_log.csv'})")
    return 0


_AUGMENT_FLAGS = {"refiner": "refiner", "examiner": "examiner", "per_frame": "per_frame", "threshold": "threshold",
                  "augment_start": "start", "augment_refresh": "refresh", "augment_pool": "pool",
                  "augment_share": "share", "augment_weight": "weight", "augment_detail_sigma": "detail_sigma",
                  "augment_mask": "mask", "augment_unknown_weight": "unknown_weight", "augment_sources": "align_sources",
                  "augment_keep_carried": "keep_carried", "augment_texture": "align_texture"}


def augment_config(args: argparse.Namespace):
    """The AugmentConfig of --augment and its options (paths made absolute), or None without --augment."""
    from pathlib import Path

    from trioman.toolkit.train.augmentation import AugmentConfig

    flags = [flag for flag in _AUGMENT_FLAGS if getattr(args, flag) is not None]
    if args.augment is None:
        if flags:
            raise ValueError(f"--{flags[0].replace('_', '-')}: needs --augment coarse|aligned|refined|examined|truth|truth_seen")
        return None
    given = {_AUGMENT_FLAGS[flag]: getattr(args, flag) for flag in flags}
    for key in ("refiner", "examiner"):
        if key in given:
            if not Path(given[key]).exists():
                raise FileNotFoundError(f"--{key}: not found: {given[key]}")
            given[key] = str(Path(given[key]).resolve())
    if args.augment in ("refined", "examined"):
        given.setdefault("keep_carried", True)
    return AugmentConfig(mode=args.augment, **given)
