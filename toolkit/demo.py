"""``trioman demo``: the whole pipeline on the embedded synthetic subject.

At this stage: synthesise a subject, write its contact sheet and a turntable MP4 of the posed,
textured body mesh. Later stages (train, eval, export, augment) extend it.
"""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", default="out/demo", help="output folder (default out/demo)")
    parser.add_argument("--seed", type=int, default=0, help="subject seed (default 0)")
    parser.add_argument("--size", type=int, default=256, help="image side in pixels (default 256)")
    parser.add_argument("--frames", type=int, default=120, help="subject frames (default 120)")
    parser.add_argument("--quiet", action="store_true", help="no progress bars")


def run(args: argparse.Namespace) -> int:
    import time
    from pathlib import Path

    from trioman.toolkit.synth.subject import SynthConfig, synthesize_subject
    from trioman.toolkit.synth.turntable import write_turntable

    out = Path(args.out)
    start = time.perf_counter()
    cfg = SynthConfig(seed=args.seed, size=args.size, frames=args.frames)
    subject = synthesize_subject(cfg, out / "subject", overwrite=True, progress=not args.quiet)
    video = write_turntable(cfg, out / "turntable.mp4", progress=not args.quiet)
    print(f"demo: subject      {subject.root} ({subject.num_frames} frames)")
    print(f"demo: contact sheet {out / 'subject' / 'contact_sheet.png'}")
    print(f"demo: turntable    {video}")
    print(f"demo: done in {time.perf_counter() - start:.1f} s")
    return 0
