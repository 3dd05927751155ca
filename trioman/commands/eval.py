"""``trioman eval RUN``: metrics and pictures for a trained avatar (standard-library imports only here)."""

from __future__ import annotations

import argparse


def _configs():
    from trioman.toolkit.evaluate_config import EvalOptions

    return (EvalOptions,)


def flags() -> dict[str, str]:
    """The fields the library's errors name -> this command's flags."""
    from trioman.runtime.options import flags as option_flags

    return {**option_flags(*_configs()), "out": "--out"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from trioman.options import add_options

    parser.add_argument("run", help="run folder written by trioman train")
    parser.add_argument("--out", default=None, help="report folder (default RUN/eval_SPLIT)")
    add_options(parser, *_configs())
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from trioman.options import given
    from trioman.toolkit.evaluate import evaluate
    from trioman.toolkit.lpips import NOT_FOUND_MESSAGE, load_lpips

    (options,) = _configs()
    cfg = options(**given(options, args))
    out = Path(args.out) if args.out else Path(args.run) / f"eval_{cfg.split}"
    model = load_lpips()  # a named folder without the weights is an error before any work
    summary = evaluate(args.run, cfg.split, out, lpips=model, progress=not args.quiet,
                       video=cfg.video, protocol=cfg.protocol, poses=cfg.poses)
    if model is None:  # said with the results, never before an error about the inputs
        print(f"eval: {NOT_FOUND_MESSAGE}")
    m = summary["mean"]
    print(f"eval: {summary['frames']} {cfg.split} frames at step {summary['step']}: PSNR {m['psnr']:.2f} dB, "
          f"SSIM {m['ssim']:.4f} (masked protocol); unmasked PSNR {m['psnr_unmasked']:.2f} dB")
    if "exavatar" in summary:
        e = summary["exavatar"]
        lpips = "n/a" if e["lpips"] is None else f"{e['lpips']:.4f}"
        print(f"eval: ExAvatar's protocol: PSNR {e['psnr']:.2f} dB, SSIM {e['ssim']:.4f} (torchmetrics >= 1.5; "
              f"{e['ssim_tm14']:.4f} as <= 1.4), LPIPS {lpips}")
    print(f"eval: report {out / 'report.md'}, grid {out / 'grid.png'}" + (f", video {out / 'video.mp4'}" if cfg.video else ""))
    return 0
