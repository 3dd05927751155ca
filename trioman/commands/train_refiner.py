"""``trioman train-refiner --corpus DIR --out RUN``: train the Refiner on a synthetic corpus's training
subjects (toolkit/model_training.py); resumes a run folder that has checkpoints. Under
``torchrun --nproc-per-node N -m trioman train-refiner ...`` the N processes train one run data-parallel
(docs/scaling.md): --batch is per process, rank 0 writes the run folder."""

from __future__ import annotations

import argparse

# The parameters the library's errors name -> the flags as typed (trioman/commands/flags.py).
FLAGS = {"device": "--device", "baseline_frames": "--baseline-frames", "pretrained_path": "--pretrained"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--corpus", help="corpus folder (trioman synth-corpus): its training subjects' triplets")
    source.add_argument("--triplets", nargs="+", metavar="FILE",
                        help="triplet files instead (trioman triplets, e.g. --draws N ones of synthetic subjects)")
    parser.add_argument("--out", required=True, help="run folder (checkpoints, fit.json)")
    parser.add_argument("--conditions", choices=("none", "tex", "tex+geo", "warp", "warp+geo"), default="warp+geo",
                        help="warp / warp+geo: refine the geometry-aligned reference (the default, warp+geo, measured "
                             "best: docs/findings.md, 'Augmentation'); the paper's none / tex / tex+geo: a real frame "
                             "near the view as reference")
    parser.add_argument("--steps", type=int, default=1000)
    parser.add_argument("--batch", type=int, default=4,
                        help="samples per process and step (default 4; the global batch is this times the process count)")
    parser.add_argument("--crop", type=int, default=64, help="training crop side, a multiple of 16 (default 64)")
    parser.add_argument("--size", choices=("compact", "default"), default="compact", help="Refiner widths")
    parser.add_argument("--baseline-frames", choices=("all", "subset"), default="all", help="corpus variant")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--backbone", choices=("scratch", "sd-turbo"), default="scratch",
                        help="sd-turbo: the paper's SD-Turbo backbone from --pretrained DIR (needs trioman[diffusion])")
    parser.add_argument("--pretrained", metavar="DIR", help="local SD-Turbo folder in diffusers layout (never downloaded)")
    parser.add_argument("--device", choices=("cpu", "cuda"), default="cpu",
                        help="cpu or cuda (under torchrun each process takes the GPU of its local rank; default cpu)")
    parser.add_argument("--mixed-precision", choices=("no", "bf16"), default="no", help="bf16 autocast (CUDA)")
    parser.add_argument("--gradient-checkpointing", action="store_true", help="recompute activations (sd-turbo)")


def run(args: argparse.Namespace) -> int:
    from trioman.toolkit.distributed import process_group
    from trioman.toolkit.model_training import FitConfig, fit_refiner
    from trioman.toolkit.lpips import NOT_FOUND_MESSAGE, load_lpips
    from trioman.toolkit.loops.checkpoint import ConfigMismatch

    fit = FitConfig(steps=args.steps, batch=args.batch, crop=args.crop, seed=args.seed, baseline_frames=args.baseline_frames)
    with process_group(args.device) as ranks:
        lpips = load_lpips()  # a named folder without the weights is an error before any work
        try:
            _, info = fit_refiner(args.corpus or args.triplets, args.out, args.conditions, fit, args.size, lpips=lpips,
                                  backbone=args.backbone, pretrained=args.pretrained, device=args.device,
                                  mixed_precision=args.mixed_precision, gradient_checkpointing=args.gradient_checkpointing)
        except ConfigMismatch as err:
            raise err.with_hint(resume_hint(args, err)) from None
    if not ranks.main:
        return 0
    if lpips is None:  # rank 0 alone says it, once the run has trained, never before an error
        print(f"train-refiner: {NOT_FOUND_MESSAGE}")
    print(f"train-refiner: {info['checkpoint']} ({args.conditions}, {args.steps} steps, {info['seconds'] / 60:.1f} min, "
          f"final loss {info['final_loss']:.4f})")
    return 0


def resume_hint(args: argparse.Namespace, err) -> str:
    """What resumes the run whose Refiner (``err``: a ConfigMismatch) differs from the one these options build:
    the command with the options that build the run's Refiner, when some do."""
    from trioman.commands import command_line
    from trioman.toolkit.model_training import REFINER_SIZES
    from trioman.toolkit.refiner import RefinerConfig

    run = err.run_config
    sizes = sorted(REFINER_SIZES, key=lambda name: name != args.size) if run.get("backbone") == "scratch" else [args.size]
    for size in sizes:  # the options that build a Refiner as fit_refiner does
        options = {"crop": run.get("image_size"), "conditions": run.get("conditions"), "backbone": run.get("backbone"),
                   "pretrained": run.get("pretrained_path"), "size": size}
        widths = REFINER_SIZES[size] if options["backbone"] == "scratch" else {}
        try:
            same = RefinerConfig(image_size=options["crop"], conditions=options["conditions"], backbone=options["backbone"],
                                 pretrained_path=options["pretrained"], **widths).to_dict() == run
        except (TypeError, ValueError):
            same = False
        if same:
            words = command_line("train-refiner", add_arguments, {**vars(args), **options})
            return f"resume it with the options it was started with: `{words}` (or choose another --out)"
    return ("no options of this trioman build the run's Refiner: resume it with the trioman version that started it, "
            "or choose another --out")
