"""``trioman fit VIDEO|FRAMES_DIR --out SUBJECT``: a person's video -> a subject folder, the open Anny body fitted
to it on a CPU (toolkit/fit/run.py; docs/fit.md). Standard-library imports only at module level."""

from __future__ import annotations

import argparse

# The parameters the library's errors name -> the flags as typed (trioman/commands/flags.py).
FLAGS = {"overwrite": "--overwrite", "every": "--every", "start": "--start", "end": "--end", "max_frames": "--max-frames",
         "long_side": "--long-side", "focal": "--focal", "fov_deg": "--fov", "test_every": "--test-every",
         "key_iterations": "--key-iterations", "all_iterations": "--iterations", "keyframes": "--keyframes"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("source", help="a video file (mp4, mov, avi, ...; a phone's rotation is honoured) or a folder of frames")
    parser.add_argument("--out", required=True, help="the subject folder to write")
    parser.add_argument("--every", type=int, default=1, help="keep every N-th frame (default 1)")
    parser.add_argument("--start", type=int, default=0, help="first frame (default 0)")
    parser.add_argument("--end", type=int, default=None, help="stop before this frame (default: the end)")
    parser.add_argument("--max-frames", type=int, default=None, help="at most this many frames (default: all)")
    parser.add_argument("--long-side", type=int, default=540,
                        help="frames larger than this (pixels, the long side) are scaled down to it (default 540; 0: native)")
    camera = parser.add_mutually_exclusive_group()
    camera.add_argument("--focal", type=float, default=None, metavar="PX",
                        help="the focal length in pixels at the output size (default: a phone's, refined by the fit)")
    camera.add_argument("--fov", type=float, default=None, metavar="DEG", help="the long side's field of view in degrees")
    parser.add_argument("--test-every", type=int, default=8, help="every N-th kept frame goes to the test split (default 8; 0: none)")
    parser.add_argument("--keyframes", type=int, default=24, help="frames the shape and camera are fitted on (default 24)")
    parser.add_argument("--key-iterations", type=int, default=300, help="the keyframes' iterations (default 300)")
    parser.add_argument("--iterations", type=int, default=250, help="the iterations over every frame (default 250)")
    parser.add_argument("--overwrite", action="store_true", help="replace an existing subject folder (one of trioman's)")
    parser.add_argument("--quiet", action="store_true", help="no progress bars")


def run(args: argparse.Namespace) -> int:
    import time

    from trioman.runtime.video_input import FrameSelection
    from trioman.toolkit.fit.fitter import FitConfig
    from trioman.toolkit.fit.run import FIT_MD, OVERLAY_PNG, FitRunConfig, fit_video

    selection = FrameSelection(every=args.every, start=args.start, end=args.end, max_frames=args.max_frames,
                               long_side=args.long_side or None)
    fit = FitConfig(keyframes=args.keyframes, key_iterations=args.key_iterations, all_iterations=args.iterations)
    cfg = FitRunConfig(selection=selection, focal=args.focal, fov_deg=args.fov, test_every=args.test_every, fit=fit)
    start = time.perf_counter()
    subject = fit_video(args.source, args.out, cfg, overwrite=args.overwrite, progress=not args.quiet,
                        say=lambda line: print(f"fit: {line}", flush=True))
    n_train, n_test = len(subject.indices("train")), len(subject.indices("test"))
    print(f"fit: wrote {subject.num_frames} frames ({n_train} train, {n_test} test) at {subject.width}x{subject.height} "
          f"to {subject.root} in {time.perf_counter() - start:.1f} s")
    print(f"fit: report {subject.root / FIT_MD}, the fitted body over the frames {subject.root / OVERLAY_PNG}")
    print(f"fit: next: trioman train {subject.root} --out RUN")
    return 0
