"""``trioman bench train``: avatar quality against training time, per preset, on one synthetic subject,
and where the time of one training step goes (``bench_train``).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from trioman.bench.common import machine
from trioman.bench.config import TrainBenchConfig
from trioman.runtime.stages import lifetime_peak_rss_bytes, mib

HOLE_SIZE = 512  # animate's default output side
HOLE_ALPHA = 0.5
STAGES = ("triplane + MLPs", "posing (LBS)", "projection", "tile binning", "rasterizer forward", "loss",
          "rasterizer backward", "backward", "optimizer")  # the marks of one step (runtime.stages)


def profile_step(subject_dir: Path, preset_name: str, sizes: tuple[int, ...], threads: tuple[int, ...],
                 steps: int, warmup: int = 2) -> list[dict]:
    """Seconds per stage of one training step (the loop's own step, on the subject's training frames resized
    to each size), the mean of ``steps`` steps after ``warmup``. -> one row per (size, threads): size,
    threads, gaussians, rasterizer ("C kernel" or "torch"), step_s (wall time of the whole step), stages {name: s}: STAGES,
    then any other mark the step recorded (under its own name, so that no marked time hides in "other"), then "other",
    the step's time outside the marks (sampling a frame, the PSNR, the finite checks)."""
    import torch

    from trioman.runtime.formats import load_subject
    from trioman.runtime.stages import record_stages
    from trioman.toolkit.avatar.model import GaussianAvatar
    from trioman.toolkit.cpu import deterministic_kernels, flush_denormals
    from trioman.toolkit.train.config import preset
    from trioman.toolkit.train.data import load_frames
    from trioman.toolkit.loops.guard import StepGuard
    from trioman.toolkit.render import native
    from trioman.toolkit.train.loop import param_groups, train_step

    subject = load_subject(subject_dir)
    cfg = preset(preset_name)
    rasterizer = "C kernel" if native.load() is not None else "torch"  # what rasterize's "auto" runs on the CPU
    previous = torch.get_num_threads()
    rows = []
    try:
        for size in sizes:
            frames = load_frames(subject, "train", size / subject.width)
            for n_threads in threads:
                torch.set_num_threads(n_threads)
                model = GaussianAvatar(subject.body, cfg.avatar)
                optimizer = torch.optim.Adam(param_groups(model, cfg), lr=cfg.lr, eps=1e-15)
                gen = torch.Generator().manual_seed(cfg.seed)
                guard = StepGuard("bench", cfg.max_skipped)
                with flush_denormals(), deterministic_kernels():
                    for k in range(warmup):
                        train_step(model, optimizer, frames.sample(k % len(frames)), cfg, gen, None, guard, k)
                    with record_stages() as record:
                        t0 = time.perf_counter()
                        for k in range(steps):
                            train_step(model, optimizer, frames.sample(k % len(frames)), cfg, gen, None, guard, warmup + k)
                        wall = time.perf_counter() - t0
                stages = {name: record.get(name, 0.0) / steps for name in STAGES}
                stages.update((name, seconds / steps) for name, seconds in record.items() if name not in STAGES)
                stages["other"] = wall / steps - sum(stages.values())
                rows.append({"size": frames.width, "threads": n_threads, "gaussians": model.num_gaussians,
                             "rasterizer": rasterizer, "step_s": wall / steps, "stages": stages})
    finally:
        torch.set_num_threads(previous)
    return rows


def stage_names(rows: list[dict]) -> list[str]:
    """The stage names of the step profile's rows, in first-seen order, "other" last."""
    names = list(dict.fromkeys(name for r in rows for name in r["stages"] if name != "other"))
    return names + ["other"]


def plot_step_profile(rows: list[dict], path: Path) -> None:
    """A stacked horizontal bar per (size, threads) row (labelled by its "label" when it has one): milliseconds
    per stage of one step."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(10, 1.2 + 0.6 * len(rows)), dpi=120)
    labels = [r.get("label", f"{r['size']} px, {r['threads']} thread{'s' if r['threads'] > 1 else ''}") for r in rows]
    left = np.zeros(len(rows))
    names = stage_names(rows)
    colors = plt.get_cmap("tab10")(np.arange(len(names)) % 10)
    for name, color in zip(names, colors):
        ms = np.array([1000 * r["stages"].get(name, 0.0) for r in rows])
        ax.barh(labels, ms, left=left, color=color, label=name)
        left += ms
    ax.set_xlabel("milliseconds per step")
    ax.invert_yaxis()
    ax.legend(fontsize=7, ncol=5, loc="upper center", bbox_to_anchor=(0.5, -0.35 if len(rows) < 3 else -0.2))
    ax.set_title("One quick-preset training step, by stage")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def train_presets(config: TrainBenchConfig, out: Path) -> dict:
    from trioman.toolkit.evaluate import evaluate
    from trioman.toolkit.synth.subject import SynthConfig, synthesize_subject
    from trioman.toolkit.train.config import preset
    from trioman.runtime.outputs import remove_own
    from trioman.toolkit.train.loop import RUN_FOLDER, train

    subject_dir = out / "subject"
    if not (subject_dir / "subject.json").exists():
        synthesize_subject(SynthConfig(seed=config.seed, size=config.size, frames=config.frames), subject_dir)
    results = {}
    for name in config.presets:
        overrides = {"checkpoint_every": config.eval_every}
        if config.iterations:
            overrides["iterations"] = config.iterations
        elif name == "full" and config.full_iterations:
            overrides["iterations"] = config.full_iterations
        cfg = preset(name, **overrides)
        run = out / f"run_{name}"
        curve = []

        def on_checkpoint(step: int, path: Path, run=run, curve=curve, name=name) -> None:
            train_seconds = float((run / "train_log.csv").read_text().splitlines()[-1].split(",")[1])
            point = {"step": step, "train_seconds": train_seconds}
            for split in ("train", "test"):
                s = evaluate(run, split, out=run / f"eval_{split}_{step:07d}", progress=False, video=False, grid_frames=3)
                point[f"{split}_psnr"], point[f"{split}_ssim"] = s["mean"]["psnr"], s["mean"]["ssim"]
            curve.append(point)
            print(f"bench train [{name}] step {step}: {train_seconds:.0f} s, train PSNR {point['train_psnr']:.2f} dB, "
                  f"test PSNR {point['test_psnr']:.2f} dB", flush=True)

        remove_own(run, RUN_FOLDER)  # each benchmark trains from scratch (an earlier run of it, nothing else)
        t0 = time.perf_counter()
        train(subject_dir, run, cfg, on_checkpoint=on_checkpoint)
        wall = time.perf_counter() - t0
        last = curve[-1]
        holes = hole_fraction(run, out / f"render_{name}_{HOLE_SIZE}.png")
        results[name] = {
            "iterations": cfg.iterations, "gaussians": holes["gaussians"], "wall_seconds_incl_evals": round(wall, 1),
            "train_seconds": last["train_seconds"], "train_psnr": last["train_psnr"], "train_ssim": last["train_ssim"],
            "test_psnr": last["test_psnr"], "test_ssim": last["test_ssim"],
            "best_test_psnr": max(c["test_psnr"] for c in curve), "hole_fraction": holes["fraction"], "curve": curve,
        }
    return results


def hole_fraction(run: Path, picture: Path, size: int = HOLE_SIZE, frames: int = 4) -> dict:
    """Render test frames at ``size`` px (K scaled): the share of body pixels with opacity < HOLE_ALPHA.

    The body is the GT mask upsampled (nearest) and eroded by size / 128 px, so silhouette edges do not
    count. Writes the first frame's render (over white) beside its upsampled GT to ``picture``.
    """
    import cv2
    import torch

    from trioman.runtime.image_io import write_png
    from trioman.toolkit.evaluate import load_run
    from trioman.toolkit.render import rasterize

    model, subject, _, _ = load_run(run)
    idx = subject.indices("test")
    picks = idx[np.linspace(0, len(idx) - 1, min(frames, len(idx))).astype(int)]
    kernel = np.ones((2 * (size // 128) + 1,) * 2, np.uint8)
    holes = body = 0
    for n, i in enumerate(int(i) for i in picks):
        sx, sy = size / subject.width, size / subject.height
        K = np.array(subject.K[i], np.float64) * np.array([[sx], [sy], [1.0]])
        with torch.no_grad():
            g = model(torch.from_numpy(np.array(subject.poses[i])), torch.from_numpy(np.array(subject.trans[i]))).refined
            r = rasterize(g.means, g.quats, g.scales, g.opacities, g.colors, torch.from_numpy(np.array(subject.viewmat[i])),
                          torch.from_numpy(K).float(), size, size, background=torch.ones(3))
        mask = cv2.resize(subject.mask(i), (size, size), interpolation=cv2.INTER_NEAREST) > 0.5
        inside = cv2.erode(mask.astype(np.uint8), kernel) > 0
        alpha = r.alpha.numpy()
        holes += int((alpha[inside] < HOLE_ALPHA).sum())
        body += int(inside.sum())
        if n == 0:
            gt = cv2.resize(subject.image(i) + (1 - subject.mask(i))[..., None], (size, size), interpolation=cv2.INTER_LINEAR)
            write_png(picture, np.concatenate([gt, r.rgb.clamp(0, 1).numpy()], axis=1))
    return {"gaussians": model.num_gaussians, "fraction": holes / max(body, 1)}


def plot_curves(results: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4), dpi=120)
    for name, r in results.items():
        steps = [c["step"] for c in r["curve"]]
        minutes = [c["train_seconds"] / 60 for c in r["curve"]]
        for ax, xs in zip(axes, (steps, minutes)):
            line, = ax.plot(xs, [c["test_psnr"] for c in r["curve"]], marker="o", label=f"{name} test")
            ax.plot(xs, [c["train_psnr"] for c in r["curve"]], marker=".", ls="--", color=line.get_color(),
                    label=f"{name} train")
    axes[0].set_xlabel("iterations")
    axes[1].set_xlabel("training wall-clock time (min)")
    for ax in axes:
        ax.set_ylabel("PSNR (dB, masked protocol)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle("Training frames (dashed) and novel poses and views (solid)")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def bench_train(config: TrainBenchConfig) -> dict:
    """The report of ``trioman bench train``: the presets' curves (unless not ``config.training``), the rasterizer
    timings and the step profile.

    Each preset trains from scratch; at every checkpoint the training and test splits are evaluated (test =
    novel poses and views), outside the training clock. The finished avatar is also rendered at
    ``HOLE_SIZE`` px, where gaps between Gaussians show as holes: the share of the (upsampled, eroded) body
    mask the render leaves below ``HOLE_ALPHA`` opacity is reported. Writes train.md, train.json,
    train_psnr_vs_time.png and render_<preset>_<size>.png. The step profile (:func:`profile_step`) times
    the stages of one quick-preset step (the avatar's triplane and MLPs, posing, projection, tile binning,
    rasterizer forward, loss, backward with the rasterizer's share on its own, optimizer) at the subject's
    size and at half of it, at 1 and 2 torch threads: step_profile.png."""
    import numpy as np
    import torch

    from trioman.runtime.formats import load_subject
    from trioman.bench.raster import bench_rasterizer
    from trioman.toolkit.avatar.model import AvatarConfig, GaussianAvatar
    from trioman.toolkit.synth.subject import SynthConfig, synthesize_subject

    out = Path(config.out)
    subject_dir = out / "subject"
    if not (subject_dir / "subject.json").exists():
        synthesize_subject(SynthConfig(seed=config.seed, size=config.size, frames=config.frames), subject_dir, overwrite=True)
    report = {"target": "train", "machine": machine(), "size": config.size}
    if config.training:
        report["presets"] = train_presets(config, out)
        plot_curves(report["presets"], out / "train_psnr_vs_time.png")
    subject = load_subject(subject_dir)
    model = GaussianAvatar(subject.body, AvatarConfig())  # one Gaussian per vertex: the dense reference stays tractable
    i = int(subject.indices("train")[0])
    with torch.no_grad():
        g = model(torch.from_numpy(np.array(subject.poses[i])), torch.from_numpy(np.array(subject.trans[i]))).refined
    report["rasterizer"] = bench_rasterizer(g, torch.from_numpy(np.array(subject.viewmat[i])),
                                            torch.from_numpy(np.array(subject.K[i])), sizes=(config.size // 2, config.size))
    threads = (config.threads,) if config.threads else (1, 2)
    report["step_profile"] = profile_step(subject_dir, "quick", (config.size // 2, config.size), threads, config.repeats)
    plot_step_profile(report["step_profile"], out / "step_profile.png")
    report["peak_rss_mib"] = round(mib(lifetime_peak_rss_bytes()), 1)
    return report


def train_markdown(r: dict) -> str:
    lines = [f"# trioman bench train ({r['size']}x{r['size']} subject)", "", f"Machine: {r['machine']}.", ""]
    if "presets" in r:
        lines += ["## Avatar quality against training time", "",
                  "PSNR/SSIM under ExAvatar's masked protocol (GT mask, white background). Train = the training",
                  "frames; test = novel poses from novel views. Training time excludes the evaluations.", "",
                  "| preset | Gaussians | iterations | train time | train PSNR | train SSIM | test PSNR (best on the way) | "
                  "test SSIM | holes at 512 px |",
                  "|---|---|---|---|---|---|---|---|---|"]
        for name, p in r["presets"].items():
            lines.append(f"| {name} | {p['gaussians']} | {p['iterations']} | {p['train_seconds'] / 60:.1f} min | "
                         f"{p['train_psnr']:.2f} | {p['train_ssim']:.4f} | {p['test_psnr']:.2f} ({p['best_test_psnr']:.2f}) | "
                         f"{p['test_ssim']:.4f} | {100 * p['hole_fraction']:.2f}% |")
        lines += ["", "Holes: the share of body pixels (GT mask upsampled to 512x512, eroded 4 px) that the avatar "
                  "leaves below 0.5 opacity, over 4 test frames.", "",
                  "Per checkpoint (iteration: train / test PSNR):", ""]
        for name, p in r["presets"].items():
            lines.append(f"- {name}: " + ", ".join(f"{c['step']}: {c['train_psnr']:.2f} / {c['test_psnr']:.2f}"
                                                  for c in p["curve"]))
        lines += ["", "![PSNR against iterations and training time](train_psnr_vs_time.png)", ""]
        lines += [f"![{name} at 512 px: GT, render](render_{name}_512.png)" for name in r["presets"]] + [""]
    lines += ["## Rasterizer (an untrained avatar, one Gaussian per mesh vertex)", "",
              "Seconds per call; ratios are the reference's time over the tiled rasterizer's, measured in this run.", "",
              "| size | Gaussians | tiled fwd | tiled fwd+bwd | dense torch fwd (x) | dense fwd+bwd (x) | brute-force oracle fwd (x) |",
              "|---|---|---|---|---|---|---|"]
    for row in r["rasterizer"]:
        oracle = f"{row['oracle_fwd_s']:.2f} ({row['oracle_fwd_s'] / row['tiled_fwd_s']:.0f}x)" if "oracle_fwd_s" in row else "not run"
        lines.append(f"| {row['size']} | {row['gaussians']} | {row['tiled_fwd_s']:.3f} | {row['tiled_fwd_bwd_s']:.3f} | "
                     f"{row['dense_fwd_s']:.3f} ({row['dense_fwd_s'] / row['tiled_fwd_s']:.1f}x) | "
                     f"{row['dense_fwd_bwd_s']:.3f} ({row['dense_fwd_bwd_s'] / row['tiled_fwd_bwd_s']:.1f}x) | {oracle} |")
    lines += step_profile_markdown(r["step_profile"])
    lines += ["", f"Peak resident memory of the whole benchmark process: {r['peak_rss_mib']} MiB.", ""]
    return "\n".join(lines)


def step_profile_markdown(rows: list[dict]) -> list[str]:
    """The step profile as markdown lines: milliseconds per stage, one column per (size, threads) row."""
    names = stage_names(rows)
    lines = ["", "## One quick-preset training step, by stage", "",
             f"Milliseconds per step, the mean of the timed steps ({rows[0]['gaussians']} Gaussians, rasterizer: "
             f"{rows[0]['rasterizer']}); \"backward\" excludes the rasterizer's backward, shown on its own.", "",
             "| stage | " + " | ".join(f"{r['size']} px, {r['threads']} thr" for r in rows) + " |",
             "|---|" + "---|" * len(rows)]
    for name in names:
        lines.append(f"| {name} | " + " | ".join(f"{1000 * r['stages'].get(name, 0.0):.1f}" for r in rows) + " |")
    lines.append("| **step** | " + " | ".join(f"**{1000 * r['step_s']:.1f}**" for r in rows) + " |")
    return lines + ["", "![one step by stage](step_profile.png)"]
