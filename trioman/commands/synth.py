"""``trioman synth``: render a synthetic subject (standard-library imports only at module level)."""

from __future__ import annotations

import argparse

# The parameters the library's errors name (toolkit/synth/subject.py's SynthConfig, runtime.image_io.check_folder_target)
# -> the flags as typed; trioman/cli.py shows the errors with them (trioman/commands/flags.py).
FLAGS = {"overwrite": "--overwrite", "size": "--size", "frames": "--frames", "test_fraction": "--test-fraction",
         "pose_noise_deg": "--pose-noise", "coverage": "--coverage", "style": "--style", "capture": "--capture",
         "aspect": "--aspect", "handheld_deg": "--handheld", "outfit": "--outfit", "video": "--video", "out": "--out"}


def _aspect(text: str) -> float:
    """'9:16' or '0.5625' -> width / height."""
    w, sep, h = text.partition(":")
    try:
        return float(w) / float(h) if sep else float(text)
    except (ValueError, ZeroDivisionError):
        raise argparse.ArgumentTypeError(f"expected W:H (e.g. 9:16) or a number, got {text!r}") from None


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", required=True, help="output subject folder")
    parser.add_argument("--seed", type=int, default=0, help="body shape, clothing and noise seed (default 0)")
    parser.add_argument("--size", type=int, default=256, help="image side in pixels, the long side with --aspect (default 256)")
    parser.add_argument("--frames", type=int, default=120, help="total frames, training turn + test motions (default 120)")
    parser.add_argument("--test-fraction", type=float, default=0.2, help="fraction of frames in the test split (default 0.2)")
    parser.add_argument("--pose-noise", type=float, default=0.0, metavar="DEG",
                        help="std in degrees of the noise added to the stored poses, mimicking fitted parameters (default 0)")
    parser.add_argument("--coverage", type=float, default=1.0, metavar="FRACTION",
                        help="fraction of a full turn the training frames span, from facing the camera: 1 all round "
                             "(default), 0.5 half a turn, 0.2 front only (a capture seen from one side)")
    parser.add_argument("--style", choices=("plain", "realistic"), default="plain",
                        help="plain: painted clothes on a bald body on black (default); realistic: hair, garments and "
                             "shoes of their own geometry, a room, a key light with soft shadows, a hand-held phone's "
                             "jitter, exposure drift, motion blur, noise and JPEG")
    parser.add_argument("--capture", choices=("turn", "steps"), default="turn",
                        help="the training motion: turn in place (default), or a few steps towards the camera, then the turn")
    parser.add_argument("--aspect", type=_aspect, default=1.0, metavar="W:H",
                        help="image aspect, e.g. 9:16 for a portrait phone video (default 1:1)")
    parser.add_argument("--handheld", type=float, default=0.3, metavar="DEG",
                        help="realistic style: std of the phone's rotation jitter in degrees, 0 for a tripod (default 0.3)")
    parser.add_argument("--outfit", default="", metavar="TOP,BOTTOM,HAIR,OUTER",
                        help="realistic style: e.g. tshirt,skirt,long,none (default: drawn from the seed)")
    parser.add_argument("--video", metavar="FILE.mp4",
                        help="also write the training frames as the video a user would have (background, sensor and all; "
                             "video frame k is the subject's frame k), outside the subject folder")
    parser.add_argument("--overwrite", action="store_true", help="replace an existing subject folder")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    import time
    from pathlib import Path

    from trioman.toolkit.synth.subject import SynthConfig, synthesize_subject

    cfg = SynthConfig(seed=args.seed, size=args.size, frames=args.frames, test_fraction=args.test_fraction,
                      pose_noise_deg=args.pose_noise, coverage=args.coverage, style=args.style, capture=args.capture,
                      aspect=args.aspect, handheld_deg=args.handheld, outfit=args.outfit)
    start = time.perf_counter()
    subject = synthesize_subject(cfg, args.out, overwrite=args.overwrite, progress=not args.quiet, video=args.video)
    seconds = time.perf_counter() - start
    n_train, n_test = len(subject.indices("train")), len(subject.indices("test"))
    print(f"synth: wrote {subject.num_frames} frames ({n_train} train, {n_test} test) "
          f"at {cfg.width}x{cfg.height} ({cfg.style}) to {subject.root} in {seconds:.1f} s")
    print(f"synth: contact sheet {Path(args.out) / 'contact_sheet.png'}")
    if args.video:
        print(f"synth: video {args.video} ({n_train} training frames at 30 fps)")
    return 0
