"""``trioman bench TARGET``: benchmarks that write a markdown table and JSON to a folder.

Targets: ``synth`` (time per stage and peak memory of synthesising a subject); ``train`` (avatar
quality against training time per preset, and the rasterizer's speed against the brute-force and
dense references); ``render`` (the numpy runtime renderer against the torch rasterizer's forward and
the brute-force oracle, and the cost of Gaussians the view does not need); ``models`` (Refiner and
Examiner trained on a synthetic corpus, evaluated on held-out subjects); ``deploy`` (error against run
time of the renderer variants, the exported models per precision and optimisation level, and the
augment loop's stages); ``ablation`` (the paper's Tables 1 and 2: avatars trained with and without
online augmentation on held-out subjects). Timings are wall clock on
the machine named in the report; nothing here is a timed test.
"""

from __future__ import annotations

import argparse

TARGETS = ("synth", "train", "render", "models", "deploy", "ablation")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("target", choices=TARGETS, help="what to benchmark")
    parser.add_argument("--out", default="out/bench", help="report folder (default out/bench)")
    parser.add_argument("--size", type=int, default=None, help="image side (default: synth/train 256, models 128)")
    parser.add_argument("--frames", type=int, default=None, help="subject frames (default: synth 300, train 120)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--presets", default="quick,full", help="train: presets to run, comma-separated")
    parser.add_argument("--full-iterations", type=int, default=None, help="train: cap the full preset's iterations")
    parser.add_argument("--eval-every", type=int, default=250, help="train: test evaluation interval (iterations)")
    parser.add_argument("--no-training", action="store_true", help="train: only the rasterizer timings")
    parser.add_argument("--avatar-run", default=None, metavar="RUN",
                        help="render: a trained run folder (default: the untrained default avatar)")
    parser.add_argument("--corpus", default="out/corpus", help="models: corpus folder, built when absent (default out/corpus)")
    parser.add_argument("--subjects", type=int, default=10, help="models: training subjects when building the corpus")
    parser.add_argument("--heldout", type=int, default=None,
                        help="models/ablation: held-out subjects when building the corpus (default models 2, ablation 3)")
    parser.add_argument("--refiner-steps", type=int, default=1000, help="models: Refiner training steps per condition")
    parser.add_argument("--refiner-size", choices=("compact", "default"), default="compact", help="models: Refiner widths")
    parser.add_argument("--crop", type=int, default=64, help="models: Refiner training crop side (default 64)")
    parser.add_argument("--examiner-steps", type=int, default=1000, help="models: Examiner training steps")
    parser.add_argument("--batch", type=int, default=4, help="models: training batch size")
    parser.add_argument("--baseline-frames", default="all",
                        help="models: corpus variants for the coarse frames, e.g. all,subset (each extra one adds a tex+geo Refiner)")
    parser.add_argument("--examiner", default="examiner_nano", help="models: Examiner config name (default examiner_nano)")
    parser.add_argument("--models", default="out/bench_models",
                        help="deploy: the `bench models` report folder whose trained runs are exported (default out/bench_models)")
    parser.add_argument("--repeats", type=int, default=5, help="deploy: timed calls per variant (the best counts)")
    parser.add_argument("--threads", type=int, default=None, help="deploy: onnxruntime intra-op threads (default: ORT's)")
    parser.add_argument("--augment-frames", type=int, default=8, help="deploy: source frames of the augment run")
    parser.add_argument("--seeds", type=int, default=2, help="ablation: seeds of the baseline and the full system (default 2)")
    parser.add_argument("--iterations", type=int, default=None,
                        help="train: every preset's iterations; ablation: real-frame steps of every avatar run (default 600)")
    parser.add_argument("--ablation-subjects", default=None, metavar="NAMES",
                        help="ablation: comma-separated held-out subjects of the corpus (default: all of them)")


def _machine() -> str:
    import os
    import platform

    return f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}"


def _peak_rss_mib() -> float:
    import resource
    import sys

    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return rss / (1024 * 1024) if sys.platform == "darwin" else rss / 1024


def bench_synth(args: argparse.Namespace) -> dict:
    import shutil
    import tempfile
    import time
    from pathlib import Path

    from trioman.toolkit.synth.shading import render_textured
    from trioman.toolkit.synth.subject import SynthConfig, build_body, plan_sequences, synthesize_subject
    from trioman.toolkit.synth.texture import bake_texture

    cfg = SynthConfig(seed=args.seed, size=args.size, frames=args.frames or 300)
    work = Path(tempfile.mkdtemp(prefix="trioman-bench-"))
    try:
        t0 = time.perf_counter()
        subject = synthesize_subject(cfg, work / "subject", progress=True)
        total = time.perf_counter() - t0
        peak = _peak_rss_mib()
        # Stage breakdown, measured again separately (the end-to-end number above is the one that counts).
        t = time.perf_counter()
        mesh, _ = build_body(cfg)
        t_body = time.perf_counter() - t
        t = time.perf_counter()
        texture = bake_texture(mesh, cfg.seed, cfg.texture_size)
        t_tex = time.perf_counter() - t
        seq = plan_sequences(mesh, cfg)
        n = min(30, cfg.frames)
        t = time.perf_counter()
        verts = [mesh.pose(seq.pose[i], seq.trans[i]) for i in range(n)]
        t_pose = (time.perf_counter() - t) / n
        t = time.perf_counter()
        for i in range(n):
            render_textured(mesh, verts[i], texture, seq.viewmat[i], seq.K[i], cfg.size, cfg.size, cfg.supersample)
        t_render = (time.perf_counter() - t) / n
        return {
            "target": "synth", "machine": _machine(), "size": cfg.size, "frames": cfg.frames,
            "frames_written": subject.num_frames, "total_s": round(total, 2), "peak_rss_mib": round(peak, 1),
            "body_model_s": round(t_body, 3), "texture_bake_s": round(t_tex, 3),
            "pose_ms_per_frame": round(1e3 * t_pose, 2), "render_ms_per_frame": round(1e3 * t_render, 2),
            "target_total_s": 120,
        }
    finally:
        shutil.rmtree(work, ignore_errors=True)


def _synth_markdown(r: dict) -> str:
    ok = "yes" if r["total_s"] <= r["target_total_s"] else "NO"
    return "\n".join([
        f"# trioman bench synth ({r['size']}x{r['size']}, {r['frames']} frames)",
        "",
        f"Machine: {r['machine']}. Command: `trioman bench synth --size {r['size']} --frames {r['frames']}`.",
        "",
        "| quantity | value |",
        "|---|---|",
        f"| end-to-end `synth` wall time | {r['total_s']} s (target <= {r['target_total_s']} s: {ok}) |",
        f"| peak resident memory (whole process) | {r['peak_rss_mib']} MiB |",
        f"| body model (Anny, cached) | {r['body_model_s']} s |",
        f"| texture bake | {r['texture_bake_s']} s |",
        f"| LBS per frame | {r['pose_ms_per_frame']} ms |",
        f"| render per frame (2x2 supersampled) | {r['render_ms_per_frame']} ms |",
        "",
    ])


def bench_train(args: argparse.Namespace) -> dict:
    from pathlib import Path

    import numpy as np
    import torch

    from trioman.runtime.formats import load_subject
    from trioman.toolkit.avatar.model import GaussianAvatar
    from trioman.toolkit.bench_raster import bench_rasterizer
    from trioman.toolkit.bench_train import bench_train as run_presets, plot_curves
    from trioman.toolkit.synth.subject import SynthConfig, synthesize_subject
    from trioman.toolkit.train.config import preset

    out = Path(args.out)
    subject_dir = out / "subject"
    if not (subject_dir / "subject.json").exists():
        synthesize_subject(SynthConfig(seed=args.seed, size=args.size, frames=args.frames or 120), subject_dir, overwrite=True)
    report = {"target": "train", "machine": _machine(), "size": args.size}
    if not args.no_training:
        report["presets"] = run_presets(args, out)
        plot_curves(report["presets"], out / "train_psnr_vs_time.png")
    subject = load_subject(subject_dir)
    model = GaussianAvatar(subject.body, preset("quick").avatar)
    i = int(subject.indices("train")[0])
    with torch.no_grad():
        g = model(torch.from_numpy(np.array(subject.poses[i])), torch.from_numpy(np.array(subject.trans[i]))).refined
    report["rasterizer"] = bench_rasterizer(g, torch.from_numpy(np.array(subject.viewmat[i])),
                                            torch.from_numpy(np.array(subject.K[i])), sizes=(args.size // 2, args.size))
    report["peak_rss_mib"] = round(_peak_rss_mib(), 1)
    return report


def _train_markdown(r: dict) -> str:
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
    lines += ["## Rasterizer (default avatar)", "",
              "Seconds per call; ratios are the reference's time over the tiled rasterizer's, measured in this run.", "",
              "| size | Gaussians | tiled fwd | tiled fwd+bwd | dense torch fwd (x) | dense fwd+bwd (x) | brute-force oracle fwd (x) |",
              "|---|---|---|---|---|---|---|"]
    for row in r["rasterizer"]:
        oracle = f"{row['oracle_fwd_s']:.2f} ({row['oracle_fwd_s'] / row['tiled_fwd_s']:.0f}x)" if "oracle_fwd_s" in row else "not run"
        lines.append(f"| {row['size']} | {row['gaussians']} | {row['tiled_fwd_s']:.3f} | {row['tiled_fwd_bwd_s']:.3f} | "
                     f"{row['dense_fwd_s']:.3f} ({row['dense_fwd_s'] / row['tiled_fwd_s']:.1f}x) | "
                     f"{row['dense_fwd_bwd_s']:.3f} ({row['dense_fwd_bwd_s'] / row['tiled_fwd_bwd_s']:.1f}x) | {oracle} |")
    lines += ["", f"Peak resident memory of the whole benchmark process: {r['peak_rss_mib']} MiB.", ""]
    return "\n".join(lines)


def bench_render(args: argparse.Namespace) -> dict:
    import torch

    from trioman.toolkit.bench_render import avatar_scene, bench_renderers

    report = {"target": "render", "machine": _machine(), "torch_threads": torch.get_num_threads()}
    report.update(bench_renderers(avatar_scene(args.avatar_run)))
    report["peak_rss_mib"] = round(_peak_rss_mib(), 1)
    return report


def _render_markdown(r: dict) -> str:
    lines = [f"# trioman bench render ({r['source']})", "",
             f"Machine: {r['machine']}; torch uses {r['torch_threads']} threads, numpy one (BLAS may use more). "
             "Best of 7 calls each, measured side by side in this run. numpy: `trioman.runtime.render.rasterize`; "
             "torch: `trioman.toolkit.render.rasterize` forward under `torch.no_grad()`.", "",
             "| size | Gaussians | numpy fps (ms) | torch fwd fps (ms) | numpy speed / torch | "
             "max abs diff rgb / alpha / depth |",
             "|---|---|---|---|---|---|"]
    for row in r["rows"]:
        lines.append(f"| {row['size']} | {row['gaussians']} | {1 / row['numpy_s']:.1f} ({1e3 * row['numpy_s']:.1f}) | "
                     f"{1 / row['torch_s']:.1f} ({1e3 * row['torch_s']:.1f}) | {row['torch_s'] / row['numpy_s']:.2f}x | "
                     f"{row['max_abs_diff_rgb']:.1e} / {row['max_abs_diff_alpha']:.1e} / {row['max_abs_diff_depth']:.1e} |")
    lines += ["", "With 10x as many extra Gaussians, half behind the camera and half beside the view "
              "(target for numpy: <= 1.3x the time):", "",
              "| size | Gaussians | numpy ms (x without) | torch ms (x without) |", "|---|---|---|---|"]
    for row in r["rows"]:
        n = 11 * row["gaussians"]
        lines.append(f"| {row['size']} | {n} | {1e3 * row['extra_numpy_s']:.1f} ({row['extra_numpy_s'] / row['numpy_s']:.2f}x) | "
                     f"{1e3 * row['extra_torch_s']:.1f} ({row['extra_torch_s'] / row['torch_s']:.2f}x) |")
    lines += ["", "Memory: tracemalloc peak of one numpy render call "
              + ", ".join(f"{row['size']}: {row['numpy_tracemalloc_peak_mib']:.1f} MiB "
                          f"({row['extra_numpy_tracemalloc_peak_mib']:.1f} MiB with the extras)" for row in r["rows"])
              + f"; peak resident memory of the whole benchmark process {r['peak_rss_mib']} MiB.", ""]
    if "oracle" in r:
        o = r["oracle"]
        lines += [f"Brute-force oracle (trioman.runtime.render._reference, float64, every Gaussian at every pixel), "
                  f"one call at {o['size']}x{o['size']}: {o['oracle_s']:.1f} s against {1e3 * o['numpy_s']:.1f} ms for numpy "
                  f"({o['oracle_s'] / o['numpy_s']:.0f}x).", ""]
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    import json
    from pathlib import Path

    from trioman.runtime.image_io import atomic_write_text

    if args.size is None:
        args.size = 128 if args.target in ("models", "ablation") else 256
    if args.heldout is None:
        args.heldout = 3 if args.target == "ablation" else 2
    if args.target in ("models", "deploy", "ablation"):
        if args.target == "models":
            from trioman.toolkit.bench_models import bench_models as bench, models_markdown as markdown
        elif args.target == "ablation":
            from trioman.toolkit.bench_ablation import ablation_markdown as markdown, bench_ablation as bench
        else:
            from trioman.toolkit.bench_deploy import bench_deploy as bench, deploy_markdown as markdown

        report = bench(args)
        report["machine"], report["peak_rss_mib"] = _machine(), _peak_rss_mib()
    else:
        report = {"synth": bench_synth, "train": bench_train, "render": bench_render}[args.target](args)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out / f"{args.target}.json", json.dumps(report, indent=2) + "\n")
    md = (markdown(report) if args.target in ("models", "deploy", "ablation") else
          {"synth": _synth_markdown, "train": _train_markdown, "render": _render_markdown}[args.target](report))
    atomic_write_text(out / f"{args.target}.md", md)
    print(md)
    print(f"bench: report {out / (args.target + '.md')}")
    return 0
