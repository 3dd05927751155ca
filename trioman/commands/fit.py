"""``trioman fit VIDEO|FRAMES_DIR --out SUBJECT``: a person's video -> a subject folder, the open Anny body fitted
to it on a CPU (toolkit/fit/run.py; docs/fit.md). Standard-library imports only at module level."""

from __future__ import annotations

import argparse

def _configs():
    from trioman.runtime.frame_selection import FrameSelection
    from trioman.toolkit.fit.config import FitConfig, FitRunConfig

    return FrameSelection, FitRunConfig, FitConfig


def flags() -> dict[str, str]:
    """The fields the library's errors name -> this command's flags."""
    from trioman.runtime.options import flags as option_flags

    return {"overwrite": "--overwrite", "out": "--out", **option_flags(*_configs())}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from trioman.options import add_options

    parser.add_argument("source", help="a video file (mp4, mov, avi, ...; a phone's rotation is honoured) or a folder of frames")
    parser.add_argument("--out", required=True, help="the subject folder to write")
    for config in _configs():
        add_options(parser, config)
    parser.add_argument("--overwrite", action="store_true", help="replace an existing subject folder (one of trioman's)")
    parser.add_argument("--quiet", action="store_true", help="no progress bars")


def run(args: argparse.Namespace) -> int:
    import time

    from trioman.options import given
    from trioman.toolkit.fit.run import FIT_MD, OVERLAY_PNG, fit_video

    frames, run_config, fit_config = _configs()
    cfg = run_config(selection=frames(**given(frames, args)), fit=fit_config(**given(fit_config, args)), **given(run_config, args))
    start = time.perf_counter()
    subject = fit_video(args.source, args.out, cfg, overwrite=args.overwrite, progress=not args.quiet,
                        say=lambda line: print(f"fit: {line}", flush=True))
    n_train, n_test = len(subject.indices("train")), len(subject.indices("test"))
    print(f"fit: wrote {subject.num_frames} frames ({n_train} train, {n_test} test) at {subject.width}x{subject.height} "
          f"to {subject.root} in {time.perf_counter() - start:.1f} s")
    print(f"fit: report {subject.root / FIT_MD}, the fitted body over the frames {subject.root / OVERLAY_PNG}")
    print(f"fit: next: trioman train {subject.root} --out RUN")
    return 0
