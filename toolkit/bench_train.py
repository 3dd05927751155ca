"""``trioman bench train``: avatar quality against training time, per preset, on one synthetic subject.

Each preset trains from scratch; at every checkpoint the test split (novel poses and views) is
evaluated, outside the training clock. Writes train.md, train.json and train_psnr_vs_time.png.
"""

from __future__ import annotations

import argparse
import shutil
import time
from pathlib import Path


def bench_train(args: argparse.Namespace, out: Path) -> dict:
    from trioman.toolkit.evaluate import evaluate
    from trioman.toolkit.synth.subject import SynthConfig, synthesize_subject
    from trioman.toolkit.train.config import preset
    from trioman.toolkit.train.loop import train

    subject_dir = out / "subject"
    if not (subject_dir / "subject.json").exists():
        synthesize_subject(SynthConfig(seed=args.seed, size=args.size, frames=args.frames), subject_dir)
    results = {}
    for name in args.presets.split(","):
        overrides = {"checkpoint_every": args.eval_every}
        if name == "full" and args.full_iterations:
            overrides["iterations"] = args.full_iterations
        cfg = preset(name, **overrides)
        run = out / f"run_{name}"
        curve = []

        def on_checkpoint(step: int, path: Path, run=run, curve=curve, name=name) -> None:
            train_seconds = float((run / "train_log.csv").read_text().splitlines()[-1].split(",")[1])
            s = evaluate(run, "test", out=run / f"eval_test_{step:07d}", progress=False, video=False, grid_frames=3)
            curve.append({"step": step, "train_seconds": train_seconds, "test_psnr": s["mean"]["psnr"],
                          "test_ssim": s["mean"]["ssim"]})
            print(f"bench train [{name}] step {step}: {train_seconds:.0f} s, test PSNR {s['mean']['psnr']:.2f} dB")

        shutil.rmtree(run, ignore_errors=True)  # each benchmark trains from scratch
        t0 = time.perf_counter()
        train(subject_dir, run, cfg, on_checkpoint=on_checkpoint)
        wall = time.perf_counter() - t0
        seen = evaluate(run, "train", progress=False, video=False)
        test = evaluate(run, "test", progress=False)
        results[name] = {
            "iterations": cfg.iterations, "wall_seconds_incl_evals": round(wall, 1),
            "train_seconds": curve[-1]["train_seconds"] if curve else None,
            "train_psnr": seen["mean"]["psnr"], "train_ssim": seen["mean"]["ssim"],
            "test_psnr": test["mean"]["psnr"], "test_ssim": test["mean"]["ssim"], "curve": curve,
        }
    return results


def plot_curves(results: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4), dpi=120)
    for name, r in results.items():
        xs = [c["train_seconds"] / 60 for c in r["curve"]]
        ys = [c["test_psnr"] for c in r["curve"]]
        ax.plot(xs, ys, marker="o", label=f"{name} ({r['iterations']} it)")
    ax.set_xlabel("training wall-clock time (min, 2-core CPU)")
    ax.set_ylabel("test PSNR (dB, masked protocol)")
    ax.set_title("Novel-pose test PSNR against training time")
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
