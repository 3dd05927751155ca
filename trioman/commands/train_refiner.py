"""``trioman train-refiner --corpus DIR --out RUN``: train the Refiner on a synthetic corpus's training
subjects (toolkit/model_training.py); resumes a run folder that has checkpoints. Under
``torchrun --nproc-per-node N -m trioman train-refiner ...`` the N processes train one run data-parallel
(docs/scaling.md): --batch is per process, rank 0 writes the run folder."""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--corpus", required=True, help="corpus folder (trioman synth-corpus)")
    parser.add_argument("--out", required=True, help="run folder (checkpoints, fit.json)")
    parser.add_argument("--conditions", choices=("none", "tex", "tex+geo"), default="tex+geo")
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
    from trioman.toolkit.lpips import load_lpips, load_lpips_or_say_why

    fit = FitConfig(steps=args.steps, batch=args.batch, crop=args.crop, seed=args.seed, baseline_frames=args.baseline_frames)
    with process_group(args.device) as ranks:
        lpips = load_lpips_or_say_why("train-refiner") if ranks.main else load_lpips()  # rank 0 alone says why
        _, info = fit_refiner(args.corpus, args.out, args.conditions, fit, args.size, lpips=lpips,
                              backbone=args.backbone, pretrained=args.pretrained, device=args.device,
                              mixed_precision=args.mixed_precision, gradient_checkpointing=args.gradient_checkpointing)
    if not ranks.main:
        return 0
    print(f"train-refiner: {info['checkpoint']} ({args.conditions}, {args.steps} steps, {info['seconds'] / 60:.1f} min, "
          f"final loss {info['final_loss']:.4f})")
    return 0
