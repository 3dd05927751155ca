"""Renderer timings for ``trioman bench render``: the numpy runtime renderer against the torch
rasterizer's forward pass and the brute-force test oracle, measured side by side on one avatar in one
run, plus the cost of Gaussians the view does not need (off screen, behind the camera), and the numpy
renderer's time per stage (:func:`stage_profile`) on the default (13.7k), quick (54.8k) and full (219k)
avatars."""

from __future__ import annotations

import time
import tracemalloc

import numpy as np
import torch

from trioman.bench.common import best_time, machine
from trioman.bench.config import RenderBenchConfig
from trioman.runtime.stages import lifetime_peak_rss_bytes, mib
from trioman.runtime.render import rasterize as rasterize_numpy
from trioman.runtime.render.reference import rasterize_reference
from trioman.toolkit.render import rasterize as rasterize_torch

KEYS = ("means", "quats", "scales", "opacities", "colors")


def avatar_scene(avatar_run: str | None = None, avatar_cfg=None) -> dict:
    """Gaussians (float32 numpy) of an avatar at its first test frame's pose, with that frame's camera
    (K for a square image of side 2 cx, rescaled per size later). ``avatar_run``: a trained run folder;
    None: an untrained avatar (``avatar_cfg``, default ``AvatarConfig()``) of the default synthetic subject."""
    if avatar_run is not None:
        from trioman.toolkit.evaluate import load_run

        model, subject, _, _ = load_run(avatar_run)
        i = int(subject.indices("test")[0])
        pose, trans = np.array(subject.poses[i]), np.array(subject.trans[i])
        viewmat, K = np.array(subject.viewmat[i]), np.array(subject.K[i])
        source = f"trained run {avatar_run}, test frame {i}"
    else:
        from trioman.toolkit.avatar.model import AvatarConfig, GaussianAvatar
        from trioman.toolkit.synth.subject import SynthConfig, build_body, plan_sequences

        cfg = SynthConfig(seed=0)
        mesh = build_body(cfg)[0]
        model = GaussianAvatar(mesh, avatar_cfg or AvatarConfig())
        seq = plan_sequences(mesh, cfg)
        i = seq.split.index("test")
        pose, trans, viewmat, K = seq.pose[i], seq.trans[i], seq.viewmat[i], seq.K[i]
        source = f"{'default' if avatar_cfg is None else 'an'} avatar (untrained), first test frame ({seq.sequence[i]})"
    with torch.no_grad():
        g = model.eval()(torch.from_numpy(np.asarray(pose, np.float32)), torch.from_numpy(np.asarray(trans, np.float32)))
    scene = {k: getattr(g.refined, k).numpy().astype(np.float32) for k in KEYS}
    return dict(scene, viewmat=np.asarray(viewmat, np.float32), K=np.asarray(K, np.float64), source=source)


def with_unneeded_extras(scene: dict, factor: int = 10, seed: int = 0) -> dict:
    """The scene plus factor x N Gaussians like the avatar's, half behind the camera, half beside the
    view (at 1.5 - 3 half-widths off axis), none reaching the image."""
    rng = np.random.default_rng(seed)
    n = factor * len(scene["means"])
    K, vm = scene["K"], scene["viewmat"].astype(np.float64)
    z = np.concatenate([rng.uniform(-4.0, -0.05, n // 2), rng.uniform(1.0, 6.0, n - n // 2)])
    half = np.array([K[0, 2] / K[0, 0], K[1, 2] / K[1, 1]])  # tan of the half fields of view
    xy = rng.uniform(-2.0, 2.0, (n, 2)) * half * np.abs(z)[:, None]
    side = np.arange(n) >= n // 2
    xy[side, 0] = rng.choice([-1.0, 1.0], side.sum()) * rng.uniform(1.5, 3.0, side.sum()) * half[0] * z[side]
    cam = np.concatenate([xy, z[:, None]], 1)
    world = (cam - vm[:3, 3]) @ vm[:3, :3]  # inverse of the rigid world -> camera map
    pick = rng.integers(0, len(scene["means"]), n)
    extra = dict(means=world, quats=scene["quats"][pick], scales=scene["scales"][pick],
                 opacities=scene["opacities"][pick], colors=scene["colors"][pick])
    return dict(scene, **{k: np.concatenate([scene[k], extra[k].astype(np.float32)]) for k in KEYS})


def scene_args(scene: dict, size: int) -> list:
    """The rasterize arguments of ``scene`` at ``size`` x ``size`` (K rescaled)."""
    K = scene["K"].copy()
    K[:2] *= size / (2 * K[0, 2])
    return [scene[k] for k in KEYS] + [scene["viewmat"], K.astype(np.float32), size, size]


def bench_renderers(scene: dict, sizes=(256, 512), repeats: int = 7, oracle_size: int = 128) -> dict:
    """Times (s), frames per second, numpy-vs-torch differences and memory for each image size."""
    bg = np.ones(3, dtype=np.float32)
    extras = with_unneeded_extras(scene)
    rows = []
    for size in sizes:
        row = {"size": size, "gaussians": len(scene["means"])}
        for name, sc in (("", scene), ("extra_", extras)):
            a = scene_args(sc, size)
            ta = [torch.from_numpy(np.asarray(x)) if isinstance(x, np.ndarray) else x for x in a]
            row[f"{name}numpy_s"] = best_time(lambda: rasterize_numpy(*a, background=bg), repeats)
            with torch.no_grad():
                row[f"{name}torch_s"] = best_time(lambda: rasterize_torch(*ta, background=torch.from_numpy(bg)), repeats)
        a = scene_args(scene, size)
        out = rasterize_numpy(*a, background=bg)
        with torch.no_grad():
            ref = rasterize_torch(*(torch.from_numpy(np.asarray(x)) if isinstance(x, np.ndarray) else x for x in a),
                                  background=torch.from_numpy(bg))
        for key, x, y in zip(("rgb", "alpha", "depth"), out, ref):
            row[f"max_abs_diff_{key}"] = float(np.abs(x - y.numpy()).max())
        row["coverage"] = float((out.alpha > 0.5).mean())
        for name, sc in (("", scene), ("extra_", extras)):
            tracemalloc.start()
            rasterize_numpy(*scene_args(sc, size), background=bg)
            row[f"{name}numpy_tracemalloc_peak_mib"] = tracemalloc.get_traced_memory()[1] / 2**20
            tracemalloc.stop()
        rows.append(row)
    report = {"source": scene["source"], "rows": rows}
    if oracle_size:  # one call: seconds per frame at a small size, numpy timed at the same size
        a = scene_args(scene, oracle_size)
        t = time.perf_counter()
        rasterize_reference(*(np.asarray(x, np.float64) if isinstance(x, np.ndarray) else x for x in a), background=bg)
        report["oracle"] = {"size": oracle_size, "oracle_s": time.perf_counter() - t,
                            "numpy_s": best_time(lambda: rasterize_numpy(*a, background=bg), repeats)}
    return report


def stage_profile(scenes: dict[str, dict], sizes: tuple[int, ...], repeats: int = 3) -> list[dict]:
    """Milliseconds per stage of the numpy renderer (the marks of runtime.stages), the mean of ``repeats``
    calls after one warm-up, per scene and size. -> rows: scene, gaussians, size, stages {name: ms}, total_ms
    (the call's wall time; "checks" is the input checks and the rest outside the marks), fps."""
    from trioman.runtime.stages import record_stages

    bg = np.ones(3, dtype=np.float32)
    rows = []
    for name, scene in scenes.items():
        for size in sizes:
            a = scene_args(scene, size)
            rasterize_numpy(*a, background=bg)
            with record_stages() as record:
                t0 = time.perf_counter()
                for _ in range(repeats):
                    rasterize_numpy(*a, background=bg)
                total = (time.perf_counter() - t0) / repeats
            stages = {k: 1e3 * v / repeats for k, v in record.items()}
            stages["checks"] = 1e3 * total - sum(stages.values())
            rows.append({"scene": name, "gaussians": len(scene["means"]), "size": size, "stages": stages,
                         "total_ms": 1e3 * total, "fps": 1 / total})
    return rows


def bench_render(config: RenderBenchConfig) -> dict:
    """The report of ``trioman bench render`` (``config.avatar_run``, else the untrained default avatar) at
    ``config.size`` and twice it, and the stage profile on the default, quick and full avatars (untrained)."""
    from trioman.toolkit.train.config import preset

    report = {"target": "render", "machine": machine(), "torch_threads": torch.get_num_threads()}
    sizes = (config.size, 2 * config.size)
    scene = avatar_scene(None if config.avatar_run is None else str(config.avatar_run))
    report.update(bench_renderers(scene, sizes, oracle_size=min(128, config.size // 2)))
    scenes = {"default": scene, **{name: avatar_scene(None, preset(name).avatar) for name in ("quick", "full")}}
    report["stages"] = stage_profile(scenes, sizes)
    report["peak_rss_mib"] = round(mib(lifetime_peak_rss_bytes()), 1)
    return report


def render_markdown(r: dict) -> str:
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
    lines += ["## The numpy renderer by stage", "",
              "Milliseconds per call (mean of 3 after a warm-up); untrained avatars at the same pose and camera; "
              "\"checks\" is the input checks and the rest outside the marked stages.", ""]
    names = list(r["stages"][0]["stages"])
    lines += ["| avatar | Gaussians | size | " + " | ".join(names) + " | total ms | fps |",
              "|---|---|---|" + "---|" * (len(names) + 2)]
    for row in r["stages"]:
        lines.append(f"| {row['scene']} | {row['gaussians']} | {row['size']} | "
                     + " | ".join(f"{row['stages'].get(k, 0.0):.1f}" for k in names)
                     + f" | {row['total_ms']:.1f} | {row['fps']:.1f} |")
    lines.append("")
    if "oracle" in r:
        o = r["oracle"]
        lines += [f"Brute-force oracle (trioman.runtime.render.reference, float64, every Gaussian at every pixel), "
                  f"one call at {o['size']}x{o['size']}: {o['oracle_s']:.1f} s against {1e3 * o['numpy_s']:.1f} ms for numpy "
                  f"({o['oracle_s'] / o['numpy_s']:.0f}x).", ""]
    return "\n".join(lines)
