"""``trioman demo``: the whole pipeline on the embedded synthetic subject.

synth -> train (quick preset) -> eval (test and train splits) -> export the avatar -> animate it with
the runtime (numpy + onnxruntime, no torch), plus a turntable MP4 of the subject's posed mesh ->
triplets of the trained avatar -> a small Refiner and Examiner trained on the subject's own training
frames (a demo of the loop; ``trioman bench models`` trains them on a corpus of subjects) -> ONNX
export (fp32 + int8) -> ``augment`` with the runtime; prints where the report, grid, avatar, videos,
ONNX models and pseudo-GT frames are.
"""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", default="out/demo", help="output folder (default out/demo)")
    parser.add_argument("--seed", type=int, default=0, help="subject seed (default 0)")
    parser.add_argument("--size", type=int, default=256, help="image side in pixels (default 256)")
    parser.add_argument("--frames", type=int, default=120, help="subject frames (default 120)")
    parser.add_argument("--iterations", type=int, default=None, help="override the quick preset's iterations")
    parser.add_argument("--model-steps", type=int, default=300, help="Refiner and Examiner training steps (default 300)")
    parser.add_argument("--augment-frames", type=int, default=24, help="source frames to augment (default 24)")
    parser.add_argument("--quiet", action="store_true", help="no progress bars")


def run(args: argparse.Namespace) -> int:
    import shutil
    import time
    from pathlib import Path

    from trioman.export.avatar import export_avatar
    from trioman.export.onnx_models import summary_lines
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
    aug = _augment_stage(args, out, run_dir, avatar_dir, progress)
    print(f"demo: ONNX models   {aug['onnx']} (report {aug['onnx'] / 'export.json'}):")
    for line in summary_lines(aug["export"]):
        print(f"demo:   {line}")
    s, t = aug["result"]["summary"], aug["result"]["timing"]["ms_per_source_frame"]
    print(f"demo: pseudo-GT     {aug['out']} ({s['accepted']} frames kept of {s['candidates']} candidates from "
          f"{s['source_frames']} source frames, {t['total']:.0f} ms per source frame; report {aug['out'] / 'augment.json'}, "
          f"scores {aug['out'] / 'scores.png'}); train on it with trioman train {subject.root} --extra-frames {aug['out']}")
    print(f"demo: done in {time.perf_counter() - start:.0f} s")
    return 0


def _augment_stage(args: argparse.Namespace, out, run_dir, avatar_dir, progress: bool) -> dict:
    """Triplets of the trained avatar -> Refiner (tex+geo) and Examiner on the subject's training frames
    -> ONNX (fp32 + int8, parity-checked) -> augment the first training frames with the runtime."""
    import shutil

    from trioman.export.onnx_models import export_onnx
    from trioman.runtime.augment import augment
    from trioman.toolkit.model_training import FitConfig, fit_examiner, fit_refiner
    from trioman.toolkit.triplets import build_triplets

    triplets = build_triplets(run_dir, out / "triplets.npz", progress=progress)
    shutil.rmtree(out / "models", ignore_errors=True)  # fresh models, like the fresh avatar run
    steps = args.model_steps
    _, refiner = fit_refiner([triplets], out / "models" / "refiner", "tex+geo", FitConfig(steps=steps, split="train"))
    _, examiner = fit_examiner([triplets], out / "models" / "examiner",
                               fit=FitConfig(steps=steps, lr=3e-4, crop=None, image_size=min(args.size, 128), split="train"),
                               validation_subjects=0)  # one subject: nothing to validate on
    onnx = out / "onnx"
    report = export_onnx(refiner=refiner["checkpoint"], examiner=examiner["checkpoint"], out=onnx, variants=("fp32", "int8"),
                calibration=[triplets], size=args.size, overwrite=True)
    result = augment(out / "subject", avatar_dir, onnx / "refiner.onnx", out / "augmented",
                     examiner=onnx / "examiner.onnx", limit=args.augment_frames, overwrite=True, progress=progress)
    return {"onnx": onnx, "export": report, "out": out / "augmented", "result": result}
