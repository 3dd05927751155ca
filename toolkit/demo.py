"""``trioman demo``: the whole pipeline on the embedded synthetic subject.

synth -> train (quick preset) -> eval (test and train splits) -> export the avatar -> animate it with
the runtime (numpy + onnxruntime, no torch), plus a turntable MP4 of the subject's posed mesh; prints
where the report, grid, avatar and videos are.
"""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", default="out/demo", help="output folder (default out/demo)")
    parser.add_argument("--seed", type=int, default=0, help="subject seed (default 0)")
    parser.add_argument("--size", type=int, default=256, help="image side in pixels (default 256)")
    parser.add_argument("--frames", type=int, default=120, help="subject frames (default 120)")
    parser.add_argument("--iterations", type=int, default=None, help="override the quick preset's iterations")
    parser.add_argument("--quiet", action="store_true", help="no progress bars")


def run(args: argparse.Namespace) -> int:
    import shutil
    import time
    from pathlib import Path

    from trioman.export.avatar import export_avatar
    from trioman.runtime.animate import animate
    from trioman.runtime.formats.motion import motion_from_spec
    from trioman.toolkit.evaluate import evaluate
    from trioman.toolkit.synth.subject import SynthConfig, synthesize_subject
    from trioman.toolkit.synth.turntable import write_turntable
    from trioman.toolkit.train.command import load_lpips_or_say_why
    from trioman.toolkit.train.config import preset
    from trioman.toolkit.train.loop import train

    out = Path(args.out)
    progress = not args.quiet
    start = time.perf_counter()
    cfg = SynthConfig(seed=args.seed, size=args.size, frames=args.frames)
    subject = synthesize_subject(cfg, out / "subject", overwrite=True, progress=progress)
    video = write_turntable(cfg, out / "turntable.mp4", progress=progress)
    shutil.rmtree(out / "run", ignore_errors=True)  # the demo always starts a fresh run
    train_cfg = preset("quick", **({} if args.iterations is None else {"iterations": args.iterations}))
    lpips = load_lpips_or_say_why("demo")
    run_dir = train(subject.root, out / "run", train_cfg, progress=progress, lpips=lpips)
    test = evaluate(run_dir, "test", lpips=lpips, progress=progress)
    seen = evaluate(run_dir, "train", lpips=lpips, progress=progress, video=False)
    avatar_dir = out / "avatar"
    avatar, _ = export_avatar(run_dir, avatar_dir, overwrite=True)
    anims = {name: animate(avatar, motion_from_spec(name, avatar.skeleton), out / f"animate_{name}.mp4",
                           camera=camera, size=args.size, progress=progress)
             for name, camera in (("walk", "fixed"), ("wave", "orbit"))}
    print(f"demo: subject       {subject.root} ({subject.num_frames} frames), contact sheet {subject.root / 'contact_sheet.png'}")
    print(f"demo: turntable     {video}")
    print(f"demo: avatar run    {run_dir} ({train_cfg.iterations} iterations, {train_cfg.preset} preset)")
    for name, s in (("train", seen), ("test", test)):
        m = s["mean"]
        print(f"demo: {name:5s} frames  PSNR {m['psnr']:.2f} dB  SSIM {m['ssim']:.4f} (masked protocol)  "
              f"report {run_dir / f'eval_{name}' / 'report.md'}")
    print(f"demo: test grid     {run_dir / 'eval_test' / 'grid.png'}; video {run_dir / 'eval_test' / 'video.mp4'}")
    print(f"demo: avatar        {avatar_dir} ({avatar.num_gaussians} Gaussians; canonical.ply opens in splat viewers)")
    for name, r in anims.items():
        print(f"demo: animation     {r['video']} ({r['frames']} frames, {r['ms_per_frame']:.0f} ms/frame with the numpy runtime)")
    print(f"demo: done in {time.perf_counter() - start:.0f} s")
    return 0
