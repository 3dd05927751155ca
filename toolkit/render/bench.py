"""Timing of the CPU rasterizer on the default avatar: ``python -m trioman.toolkit.render.bench``.

The scene: one isotropic Gaussian per vertex of the default Anny body at rest (13,718), scale 0.75 x
the mean distance to the 6 nearest vertices (the avatar's initial scale, ~1 cm), opacity 1, random
colours, seen from the synthetic subject's training camera (3 m, 5 degrees down, the body spanning 75 %
of the image height). Reports forward and forward + backward wall times (median of ``repeats`` after
one warm-up), the pixel coverage, the number of (tile, Gaussian) pairs and, on Linux, the peak RSS
growth during the first forward + backward.

On a small machine shared with other busy processes, torch's intra-op threads can slow every
parallel op by orders of magnitude (oversubscribed OpenMP barriers); ``--threads 1`` shows the
single-core figure, which is then the stable one.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
import torch


def avatar_scene(size: int, seed: int = 0, dtype=torch.float32) -> dict:
    """The benchmark scene (needs the ``anny`` body model)."""
    from trioman.runtime.cameras import orbit_viewmat
    from trioman.toolkit.avatar.mesh_ops import knn
    from trioman.toolkit.body.registry import create_body_model
    from trioman.toolkit.synth.subject import TRAIN_VIEW, SynthConfig, framing_intrinsics

    with torch.no_grad():
        mesh = create_body_model("anny").to_skinned_mesh()
    v = mesh.vertices
    _, dist = knn(v, 6)
    scale = 0.75 * dist.mean(axis=1).clip(1e-4, None)
    center = np.array([0.0, 0.0, 0.5 * (v[:, 2].min() + v[:, 2].max())])
    viewmat = orbit_viewmat(center, np.deg2rad(TRAIN_VIEW[0]), np.deg2rad(TRAIN_VIEW[1]), TRAIN_VIEW[2])
    K = framing_intrinsics(mesh, SynthConfig(size=size))
    rng = np.random.default_rng(seed)
    n = len(v)
    t = lambda x: torch.tensor(np.asarray(x), dtype=dtype)  # noqa: E731
    return dict(means=t(v), quats=t(np.tile([1.0, 0, 0, 0], (n, 1))), scales=t(np.repeat(scale[:, None], 3, 1)),
                opacities=t(np.ones(n)), colors=t(rng.uniform(0, 1, (n, 3))), viewmat=t(viewmat), K=t(K),
                width=size, height=size)


def _peak_rss_reset() -> bool:
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


def _rss_kib(field: str) -> int | None:
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith(field + ":"):
                    return int(line.split()[1])
    except OSError:
        pass
    return None


def bench(size: int, repeats: int = 10, **kw) -> dict:
    from trioman.toolkit.render.projection import _project
    from trioman.toolkit.render.rasterize import DEFAULT_TILE, rasterize
    from trioman.toolkit.render.tiles import bin_gaussians

    scene = avatar_scene(size)
    args = [scene[k] for k in ("means", "quats", "scales", "opacities", "colors", "viewmat", "K")]
    leaves = [a.clone().requires_grad_() for a in args[:5]]

    def fwd():
        with torch.no_grad():
            return rasterize(*args, size, size, **kw)

    def fwd_bwd():
        out = rasterize(*leaves, *args[5:], size, size, **kw)
        (out.rgb.sum() + out.alpha.sum() + out.depth.sum()).backward()
        return out

    res = {"size": size, "gaussians": len(args[0])}
    small = [a[:50].clone().requires_grad_() for a in args[:5]]  # warm torch up on a tiny render
    out = rasterize(*small, *args[5:], 32, 32)
    (out.rgb.sum() + out.depth.sum()).backward()
    if _peak_rss_reset():  # then the peak of one full render, before the allocator caches its blocks
        base = _rss_kib("VmRSS")
        fwd_bwd()
        peak = _rss_kib("VmHWM")
        if base is not None and peak is not None:
            res["peak_rss_growth_mib"] = (peak - base) / 1024
    for name, fn in (("forward_s", fwd), ("forward_backward_s", fwd_bwd)):
        fn()
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            fn()
            times.append(time.perf_counter() - t0)
        res[name] = statistics.median(times)
        res[name.replace("_s", "_min_s")] = min(times)
    out = fwd()
    res["coverage"] = float((out.alpha > 0.5).float().mean())
    p = _project(*args[:4], args[5], args[6], size, size)
    res["pairs"] = int(bin_gaussians(p.means2d, p.radii, p.depths, size, size, kw.get("tile_size", DEFAULT_TILE))
                       .pair_gauss.numel())
    return res


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[128, 256])
    ap.add_argument("--repeats", type=int, default=10)
    ap.add_argument("--tile-size", type=int, default=None)
    ap.add_argument("--chunk-elements", type=int, default=None)
    ap.add_argument("--threads", type=int, default=None, help="torch intra-op threads (default: torch's)")
    a = ap.parse_args(argv)
    if a.threads:
        torch.set_num_threads(a.threads)
    kw = {}
    if a.tile_size:
        kw["tile_size"] = a.tile_size
    if a.chunk_elements:
        kw["chunk_elements"] = a.chunk_elements
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads")
    for size in a.sizes:
        r = bench(size, a.repeats, **kw)
        print(f"{size}x{size}: {r['gaussians']} Gaussians, {r['pairs']} tile pairs, coverage {r['coverage']:.1%}; "
              f"forward {1e3 * r['forward_s']:.1f} ms (min {1e3 * r['forward_min_s']:.1f}), "
              f"forward+backward {1e3 * r['forward_backward_s']:.1f} ms (min {1e3 * r['forward_backward_min_s']:.1f})"
              + (f", peak RSS +{r['peak_rss_growth_mib']:.1f} MiB" if "peak_rss_growth_mib" in r else ""))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
