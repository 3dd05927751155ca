"""``trioman eval RUN``: metrics and pictures for a trained avatar (standard-library imports only here)."""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run", help="run folder written by trioman train")
    parser.add_argument("--split", default="test", choices=("train", "test"), help="frames to evaluate (default test)")
    parser.add_argument("--out", default=None, help="report folder (default RUN/eval_SPLIT)")
    parser.add_argument("--no-video", action="store_true", help="skip the MP4")
    parser.add_argument("--protocol", default="ours", choices=("ours", "exavatar"),
                        help="exavatar: also ExAvatar's numbers (composited over white outside the GT mask, full image, "
                             "PSNR/SSIM data range 1, LPIPS-AlexNet, mean over frames)")
    parser.add_argument("--poses", default="run", choices=("run", "stored", "true", "optimised"),
                        help="render at the subject's stored poses as the run corrected them (run, default: "
                             "trioman train --refine-poses; the stored ones for a run without), at the stored poses as "
                             "they are (stored), or at the recorded ground-truth poses (true: synthetic subjects made "
                             "with --pose-noise; measures the avatar, not the pose noise), or at the run's poses refitted to each "
                             "frame's own pixels with the avatar frozen (optimised: fitted videos; test-time pose "
                             "optimisation, 20 Adam steps per frame at half size)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from trioman.toolkit.evaluate import evaluate
    from trioman.toolkit.lpips import NOT_FOUND_MESSAGE, load_lpips

    out = Path(args.out) if args.out else Path(args.run) / f"eval_{args.split}"
    model = load_lpips()  # a named folder without the weights is an error before any work
    summary = evaluate(args.run, args.split, out, lpips=model, progress=not args.quiet,
                       video=not args.no_video, protocol=args.protocol, poses=args.poses)
    if model is None:  # said with the results, never before an error about the inputs
        print(f"eval: {NOT_FOUND_MESSAGE}")
    m = summary["mean"]
    print(f"eval: {summary['frames']} {args.split} frames at step {summary['step']}: PSNR {m['psnr']:.2f} dB, "
          f"SSIM {m['ssim']:.4f} (masked protocol); unmasked PSNR {m['psnr_unmasked']:.2f} dB")
    if "exavatar" in summary:
        e = summary["exavatar"]
        lpips = "n/a" if e["lpips"] is None else f"{e['lpips']:.4f}"
        print(f"eval: ExAvatar's protocol: PSNR {e['psnr']:.2f} dB, SSIM {e['ssim']:.4f} (torchmetrics >= 1.5; "
              f"{e['ssim_tm14']:.4f} as <= 1.4), LPIPS {lpips}")
    print(f"eval: report {out / 'report.md'}, grid {out / 'grid.png'}" + ("" if args.no_video else f", video {out / 'video.mp4'}"))
    return 0
