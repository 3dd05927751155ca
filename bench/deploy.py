"""``trioman bench deploy``: error against run time for what the runtime deploys (renderer, exported
models, the augment loop), as a markdown table and a scatter plot (``bench_deploy``).
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import torch

from trioman.bench.common import best_time
from trioman.bench.config import DeployBenchConfig
from trioman.bench.render import avatar_scene, scene_args
from trioman.runtime.metrics import psnr
from trioman.runtime.render.reference import rasterize_reference

OPT_LEVELS = ("disable", "basic", "extended", "all")


def _ms(fn, repeats: int) -> float:
    return 1e3 * best_time(fn, repeats)


def _psnr(a: np.ndarray, b: np.ndarray) -> float:
    """PSNR of one image pair (any layout)."""
    return float(psnr(np.asarray(a)[None], np.asarray(b)[None])[0])


def bench_renderer_rows(scene: dict, size: int, repeats: int, oracle_size: int = 128) -> list[dict]:
    """One row per renderer variant: ms per frame and max abs RGB error against torch fp32."""
    from trioman.runtime.render import rasterize as rasterize_numpy
    from trioman.toolkit.render import rasterize as rasterize_torch

    bg = np.ones(3, dtype=np.float32)

    def torch_render(a):
        ta = [torch.from_numpy(np.asarray(x)) if isinstance(x, np.ndarray) else x for x in a]

        @torch.no_grad()
        def fn():
            return rasterize_torch(*ta, background=torch.from_numpy(bg)).rgb.numpy()

        return fn

    rows = []
    a = scene_args(scene, size)
    ref_fn = torch_render(a)
    ref = ref_fn()
    rows.append({"component": "renderer", "variant": f"torch fp32 tiled fwd ({size}px, reference)", "ms": _ms(ref_fn, repeats),
                 "error": 0.0})
    for tile, extent in ((4, "opacity"), (8, "opacity"), (16, "opacity"), (4, "3sigma"), (16, "3sigma")):
        fn = lambda: rasterize_numpy(*a, background=bg, tile_size=tile, extent=extent).rgb  # noqa: E731
        rows.append({"component": "renderer", "variant": f"numpy tile {tile}, {extent} extent ({size}px)",
                     "ms": _ms(fn, repeats), "error": float(np.abs(fn() - ref).max())})
    if oracle_size:  # float64, every Gaussian at every pixel: one call, at a small size
        a = scene_args(scene, oracle_size)
        small_ref = torch_render(a)()
        t = time.perf_counter()
        out = rasterize_reference(*(np.asarray(x, np.float64) if isinstance(x, np.ndarray) else x for x in a), background=bg)
        ms = 1e3 * (time.perf_counter() - t)
        rows.append({"component": "renderer", "variant": f"brute-force oracle float64 ({oracle_size}px)", "ms": ms,
                     "error": float(np.abs(np.asarray(out[0]) - small_ref).max())})
    return rows


def bench_refiner_rows(ckpt: Path, onnx_dir: Path, frames, repeats: int, threads: int | None) -> list[dict]:
    """One row per Refiner variant: torch eager (the reference) and the ONNX files of ``onnx_dir`` (fp32 at each
    optimisation level, int8, fp16; a missing one noted as rejected) on ``frames`` (TripletSet.evaluation):
    ms per frame (batch 1, onnxruntime ``threads``), max abs error against torch, PSNR against the GT."""
    from trioman.runtime.onnx_models import RefinerModel
    from trioman.toolkit.corpus.training import refiner_batch
    from trioman.toolkit.refiner import load_refiner, refiner_inputs

    model = load_refiner(ckpt)
    cond = model.config.conditions
    b = refiner_batch(frames)
    inputs = [x.numpy() for x in refiner_inputs(b, cond)]  # NCHW float32
    gt = b.target.numpy()
    with torch.no_grad():
        ref = np.concatenate([model(*(torch.from_numpy(x[i:i + 1]) for x in inputs))[:, 0].numpy() for i in range(len(gt))])
        one = [torch.from_numpy(x[:1]) for x in inputs]
        rows = [{"component": "refiner", "variant": "torch eager fp32 (reference)", "ms": _ms(lambda: model(*one), repeats),
                 "error": 0.0, "psnr": _psnr(ref, gt)}]
    files = [("fp32", "refiner.onnx", OPT_LEVELS), ("int8", "refiner.int8.onnx", ("all",)), ("fp16", "refiner.fp16.onnx", ("all",))]
    for precision, name, levels in files:
        if not (onnx_dir / name).is_file():
            rows.append({"component": "refiner", "variant": f"onnxruntime {precision}", "ms": None, "error": None,
                         "note": "not exported (rejected by its gate, see export.json)"})
            continue
        for level in levels:
            m = RefinerModel(onnx_dir / name, optimization=level, threads=threads)
            out = np.concatenate([m.run(*(x[i:i + 1] for x in inputs))[:, 0] for i in range(len(gt))])
            rows.append({"component": "refiner", "variant": f"onnxruntime {precision}, {level} optimisations",
                         "ms": _ms(lambda: m.run(*(x[:1] for x in inputs)), repeats),
                         "error": float(np.abs(out - ref).max()), "psnr": _psnr(out, gt)})
    return rows


def bench_examiner_rows(ckpt: Path, onnx_dir: Path, frames, repeats: int, threads: int | None) -> list[dict]:
    """One row per Examiner variant, as ``bench_refiner_rows``, on the (real, reference) and (coarse, reference)
    pairs of ``frames``: max abs score error against torch and keep/drop agreement with it."""
    from trioman.runtime.onnx_models import ExaminerModel
    from trioman.toolkit.examiner import load_examiner
    from trioman.toolkit.corpus.training import nchw

    model = load_examiner(ckpt)
    # pairs: real (I^T, reference) and coarse (I_c^T, reference), as in the AUROC of bench models
    cand = np.concatenate([nchw(frames.gt).numpy(), nchw(frames.coarse).numpy()])
    refs = np.concatenate([nchw(frames.reference).numpy()] * 2)
    with torch.no_grad():
        ref = model(torch.from_numpy(cand), torch.from_numpy(refs)).numpy()
        one = (torch.from_numpy(cand[:1]), torch.from_numpy(refs[:1]))
        rows = [{"component": "examiner", "variant": "torch eager fp32 (reference)", "ms": _ms(lambda: model(*one), repeats),
                 "error": 0.0, "agreement": 1.0}]
    keep_ref = ref >= 0.5
    files = [("fp32", "examiner.onnx", OPT_LEVELS), ("int8", "examiner.int8.onnx", ("all",)), ("fp16", "examiner.fp16.onnx", ("all",))]
    for precision, name, levels in files:
        if not (onnx_dir / name).is_file():
            rows.append({"component": "examiner", "variant": f"onnxruntime {precision}", "ms": None, "error": None,
                         "note": "not exported (rejected by its gate, see export.json)"})
            continue
        for level in levels:
            m = ExaminerModel(onnx_dir / name, optimization=level, threads=threads)
            out = m.run(cand, refs)
            rows.append({"component": "examiner", "variant": f"onnxruntime {precision}, {level} optimisations",
                         "ms": _ms(lambda: m.run(cand[:1], refs[:1]), repeats), "error": float(np.abs(out - ref).max()),
                         "agreement": float(np.mean((out >= 0.5) == keep_ref))})
    return rows


def _augment_stages(corpus: Path, onnx_dir: Path, work: Path, frames: int) -> dict:
    """Per-stage ms per frame of ``trioman augment`` on the first held-out subject, with its baseline
    exported by ``trioman export avatar``."""
    from trioman.export.avatar import export_avatar
    from trioman.runtime.augment import augment

    meta = json.loads((corpus / "corpus.json").read_text())
    name = next(s["name"] for s in meta["subjects"] if s["role"] == "heldout")
    avatar = work / f"avatar_{name}"
    if not (avatar / "avatar.json").is_file():
        export_avatar(corpus / "runs" / "heldout" / name, avatar, overwrite=True)
    out = work / f"augment_{name}"
    augment(corpus / "subjects" / name, avatar, onnx_dir / "refiner.onnx", out, onnx_dir / "examiner.onnx", limit=frames,
            overwrite=True, progress=False)
    result = json.loads((out / "augment.json").read_text())
    s = result["summary"]
    return {"subject": name, "folder": str(out), "frames": s["source_frames"], "candidates": s["candidates"],
            "accepted": s["accepted"], "ms_per_frame": result["timing"]["ms_per_source_frame"]}


def bench_deploy(config: DeployBenchConfig) -> dict:
    """The report of ``trioman bench deploy``, measured side by side in one run:

    - Renderer: the numpy runtime renderer (tile sizes, extent rule) and the brute-force float64 oracle
      against the torch tiled rasterizer's forward (fp32, the reference); max abs RGB difference.
    - Refiner: torch eager (the reference), onnxruntime fp32 at each graph optimisation level, int8
      (static QDQ per channel) and fp16, batch 1; max abs difference of the refined frame, and the task
      metric (PSNR of the refined frame against the GT) on held-out test frames.
    - Examiner: the same with the score; max abs score difference and keep/drop agreement with torch.
    - The augment loop: time per frame by stage (generate, render, normal map, refine, examine, write)
      from a ``trioman augment`` run on a held-out subject of the corpus with its exported baseline.

    Inputs come from ``trioman bench models`` (its corpus, its tex+geo Refiner and its Examiner runs).
    """
    from trioman.export.onnx_models import export_onnx
    from trioman.toolkit.corpus.build import triplet_paths
    from trioman.toolkit.loops.checkpoint import model_checkpoint
    from trioman.toolkit.corpus.triplets import TripletSet

    corpus, models = Path(config.corpus), Path(config.models)
    ckpts = {}
    for key, run in (("refiner", models / "runs" / "refiner_tex_geo"), ("examiner", models / "runs" / "examiner")):
        ckpts[key] = model_checkpoint(run) if run.is_dir() else None
        if ckpts[key] is None:
            raise FileNotFoundError(f"{run}: no trained {key} checkpoint; run `trioman bench models --out {models}` first")
    out = Path(config.out)
    out.mkdir(parents=True, exist_ok=True)
    heldout = triplet_paths(corpus)["heldout"]
    frames = TripletSet.load(heldout).evaluation("test")
    frames = frames._replace(**{k: getattr(frames, k)[: config.frames] for k in frames._fields})
    size = int(frames.gt.shape[1])
    onnx_dir = out / "onnx"
    t = time.perf_counter()
    export = export_onnx(refiner=ckpts["refiner"], examiner=ckpts["examiner"], out=onnx_dir, variants=("fp32", "int8", "fp16"),
                         calibration=triplet_paths(corpus)["train"][:2], size=size, overwrite=True)
    export_s = time.perf_counter() - t
    threads = config.threads
    avatar_run = None if config.avatar_run is None else str(config.avatar_run)
    rows = bench_renderer_rows(avatar_scene(avatar_run), config.size, config.repeats)
    rows += bench_refiner_rows(ckpts["refiner"], onnx_dir, frames, config.repeats, threads)
    rows += bench_examiner_rows(ckpts["examiner"], onnx_dir, frames, config.repeats, threads)
    report = {"rows": rows, "refiner": str(ckpts["refiner"]), "examiner": str(ckpts["examiner"]), "model_size": size,
              "frames": len(frames.gt), "export": export, "export_s": export_s, "torch_threads": torch.get_num_threads(),
              "ort_threads": threads, "render_size": config.size}
    report["augment"] = _augment_stages(corpus, onnx_dir, out, config.augment_frames)
    report["figure"] = str(out / "deploy_error_vs_time.png")
    scatter_plot(rows, Path(report["figure"]))
    return report


def scatter_plot(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    floor = 1e-9  # the references themselves (error 0) sit on this line
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    fig, axes = plt.subplots(1, 3, figsize=(14, 5.5), dpi=110)
    for ax, comp in zip(axes, ("renderer", "refiner", "examiner")):
        pts = [r for r in rows if r["component"] == comp and r["ms"] is not None]
        for i, r in enumerate(pts):
            ax.scatter(r["ms"], max(r["error"], floor), s=30, label=r["variant"], color=plt.cm.tab10(i % 10))
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("ms per frame (batch 1)")
        ax.set_ylabel("max abs error vs torch fp32" + (" (rgb)" if comp == "renderer" else " (image)" if comp == "refiner" else " (score)"))
        ax.set_title(comp)
        ax.axhline(floor, color="0.8", lw=0.8)
        ax.xaxis.set_minor_formatter(NullFormatter())
        wide = bool(pts) and max(r["ms"] for r in pts) > 30 * min(r["ms"] for r in pts)
        ax.xaxis.set_major_locator(LogLocator(subs=(1.0,) if wide else (1.0, 1.5, 2.0, 3.0, 5.0, 7.0)))
        ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
        ax.legend(fontsize=6.5, loc="upper center", bbox_to_anchor=(0.5, -0.16), ncol=1, frameon=False)
    fig.suptitle("trioman bench deploy: error against run time (the torch fp32 reference sits on the bottom line)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def deploy_markdown(r: dict) -> str:
    lines = ["# trioman bench deploy", "",
             f"Machine: {r.get('machine', '?')}; torch {r['torch_threads']} threads; onnxruntime intra-op threads "
             f"{r['ort_threads'] or 'default'}. Best of several batch-1 calls, side by side in one run. Error: max abs "
             "difference against the torch fp32 reference (renderer: RGB; Refiner: refined image; Examiner: score) over "
             f"{r['frames']} held-out test frames at {r['model_size']}x{r['model_size']} (models) / {r['render_size']}px (renderer).", "",
             "| component | variant | ms per frame | max abs error | task metric |", "|---|---|---|---|---|"]
    for row in r["rows"]:
        ms = "n/a" if row["ms"] is None else f"{row['ms']:.2f}"
        err = row.get("note") if row["error"] is None else f"{row['error']:.2e}"
        metric = (f"PSNR {row['psnr']:.2f} dB" if "psnr" in row else
                  f"keep/drop agreement {100 * row['agreement']:.1f}%" if "agreement" in row else "")
        lines.append(f"| {row['component']} | {row['variant']} | {ms} | {err} | {metric} |")
    a = r["augment"]
    lines += ["", f"![error against run time]({Path(r['figure']).name})", "",
              f"## augment loop ({a['frames']} source frames of held-out subject {a['subject']}, {a['candidates']} candidates)", "",
              "| stage | ms per source frame |", "|---|---|"]
    lines += [f"| {k} | {v:.1f} |" for k, v in a["ms_per_frame"].items()]
    lines += ["", f"ONNX export of both models, fp32 + int8 + fp16 with parity checks and gates: {r['export_s']:.1f} s "
              f"(files and gate numbers: `{Path(r['figure']).parent / 'onnx' / 'export.json'}`).", ""]
    return "\n".join(lines)
