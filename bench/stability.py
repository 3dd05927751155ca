"""``trioman bench stability``: the numerical-stability checks as one report, a row per case with its
worst error and whether every output stayed finite.

- Renderers: the numpy runtime renderer and the torch rasterizer (float32) against the float64 oracle
  (trioman.runtime.render._reference) on extreme scenes: scales 1e-6..1e2 m with anisotropy 1e6, huge
  faint Gaussians and needles from 5 cm in front of the camera (``bench.scenes.extreme_scene``), half the
  Gaussians behind the camera, opacities at 1/255 and at 1, and a scene 1e4 times larger seen from 1e4
  times farther. Error: max abs difference of RGB and alpha over the image.
- Refiner and Examiner: the torch models (randomised weights) in float32 against float64 on extreme
  images (constant black, white, 1e-8, a one-pixel checkerboard, saturated noise).
- Rotations and FK + LBS: axis-angle -> matrix (numpy float64 and float32, torch float32) against scipy's
  matrix exponential in float64 at angles near pi, at pi and tiny; the skinning transforms of a chain of
  joints all rotated by those angles (numpy and torch) against the chain composed from the exponentials.
  Error: max abs difference of the matrix entries (and of the translations, metres, for FK).
- Training: the avatar loop on a small generated subject at the preset learning rates and at 100x them.
  Error: the largest loss logged; finite: every logged loss finite and a run that ended (a non-finite
  loss stops the loop, which the row reports).

``--size`` scales nothing here; ``--iterations`` is the training cases' steps (default 30) and
``--seeds`` the extreme scenes drawn (default 2). The Refiner's and Examiner's ONNX variants (fp32, fp16,
int8) on extreme images are not in this report yet.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

from trioman.bench.common import machine

KEYS = ("means", "quats", "scales", "opacities", "colors", "viewmat", "K")
ANGLES = {"pi - 1e-3": math.pi - 1e-3, "pi - 1e-6": math.pi - 1e-6, "pi": math.pi, "pi + 1e-6": math.pi + 1e-6,
          "1e-4": 1e-4, "1e-8": 1e-8, "1e-12": 1e-12, "0": 0.0}


def _row(group: str, case: str, method: str, error: float, finite: bool, note: str = "") -> dict:
    return {"group": group, "case": case, "method": method, "worst_error": float(error), "finite": bool(finite),
            "note": note}


def render_scenes(seeds: int) -> dict[str, dict]:
    """The extreme scenes by name."""
    from trioman.bench.scenes import extreme_scene, random_scene

    scenes = {f"extreme scales and anisotropy (seed {s})": extreme_scene(s) for s in range(seeds)}
    behind = random_scene(0, n=80)
    behind["means"][::2, 2] *= -1  # every other Gaussian behind the camera
    scenes["half behind the camera"] = behind
    edge = random_scene(1, n=80)
    edge["opacities"] = np.where(np.arange(80) % 2, 1.0, 1.0 / 255)
    scenes["opacity 1/255 and 1"] = edge
    huge = random_scene(2, n=80)
    huge["means"] = huge["means"] * 1e4
    huge["scales"] = huge["scales"] * 1e4
    scenes["1e4 m scene from 1e4 times farther"] = huge
    return scenes


def renderer_rows(seeds: int = 2) -> list[dict]:
    import torch

    from trioman.runtime.render import rasterize as rasterize_numpy
    from trioman.runtime.render._reference import rasterize_reference
    from trioman.toolkit.render import rasterize as rasterize_torch

    rows = []
    bg = np.full(3, 0.5)
    for name, scene in render_scenes(seeds).items():
        W, H = scene["width"], scene["height"]
        ref_rgb, ref_alpha, _ = rasterize_reference(*(np.asarray(scene[k], np.float64) for k in KEYS), W, H, background=bg)
        f32 = [np.asarray(scene[k], np.float32) for k in KEYS]
        out = rasterize_numpy(*f32, W, H, background=bg.astype(np.float32))
        with torch.no_grad():
            t = rasterize_torch(*(torch.from_numpy(a) for a in f32), W, H, background=torch.from_numpy(bg.astype(np.float32)))
        for method, rgb, alpha in (("numpy float32", out.rgb, out.alpha), ("torch float32", t[0].numpy(), t[1].numpy())):
            err = max(np.abs(rgb - ref_rgb).max(), np.abs(alpha - ref_alpha).max())
            rows.append(_row("renderer vs float64 oracle", name, method, err,
                             np.isfinite(rgb).all() and np.isfinite(alpha).all(),
                             f"{len(scene['means'])} Gaussians, {W}x{H}, coverage {ref_alpha.mean():.2f}"))
    return rows


def gradient_rows(seeds: int = 2, directions: int = 3, eps: float = 1e-6) -> list[dict]:
    """The torch rasterizer's gradients (float64 path) against central differences along random directions
    through each input, and its float32 gradients against its float64 ones. Error: |analytic - numeric| /
    (1 + sum |g|) (directional), max |g32 - g64| / (1 + max |g64|) (float32)."""
    import torch

    from trioman.bench.scenes import extreme_scene, random_scene
    from trioman.toolkit.render import rasterize

    names = ("means", "quats", "scales", "opacities", "colors", "background")
    scenes = {"random, 25 Gaussians": random_scene(1, n=25, width=24, height=20)}
    scenes.update({f"extreme scales and anisotropy (seed {s})": extreme_scene(s) for s in range(seeds)})
    rows = []
    for name, scene in scenes.items():
        W, H = scene["width"], scene["height"]
        gen = torch.Generator().manual_seed(0)
        weights = [torch.rand(*shape, generator=gen, dtype=torch.float64) for shape in ((H, W, 3), (H, W), (H, W))]

        def inputs(dtype, scene=scene):
            xs = [torch.tensor(scene[k], dtype=dtype) for k in names[:5]] + [torch.tensor([0.3, 0.2, 0.7], dtype=dtype)]
            return [x.requires_grad_() for x in xs]

        def loss(*xs, scene=scene, weights=weights, W=W, H=H):
            dtype = xs[0].dtype
            vm, K = (torch.tensor(scene[k], dtype=dtype) for k in ("viewmat", "K"))
            out = rasterize(*xs[:5], vm, K, W, H, background=xs[5])
            wr, wa, wd = (w.to(dtype) for w in weights)
            return (out.rgb * wr).sum() + (out.alpha * wa).sum() + 0.1 * (out.depth * wd).sum()

        grads = {}
        for dtype in (torch.float32, torch.float64):
            xs = inputs(dtype)
            grads[dtype] = torch.autograd.grad(loss(*xs), xs)
        xs = [x.detach() for x in inputs(torch.float64)]
        worst, finite = 0.0, all(bool(torch.isfinite(g).all()) for gs in grads.values() for g in gs)
        for k, g in enumerate(grads[torch.float64]):
            for _ in range(directions):
                d = torch.randn(g.shape, generator=gen, dtype=torch.float64)
                if names[k] == "scales":
                    d = d * xs[k]  # relative steps: scales stay positive, tiny ones move in proportion
                plus, minus = list(xs), list(xs)
                plus[k], minus[k] = xs[k] + eps * d, xs[k] - eps * d
                with torch.no_grad():
                    numeric = (loss(*plus) - loss(*minus)) / (2 * eps)
                worst = max(worst, float(abs((g * d).sum() - numeric) / (1 + g.abs().sum())))
        rows.append(_row("rasterizer gradients", name, "torch float64 vs central differences", worst, finite,
                         f"{directions} random directions per input, eps {eps:g}"))
        f32 = max(float((g32.double() - g64).abs().max() / (1 + g64.abs().max()))
                  for g32, g64 in zip(grads[torch.float32], grads[torch.float64]))
        rows.append(_row("rasterizer gradients", name, "torch float32 vs float64", f32, finite, "per input, max over inputs"))
    return rows


def extreme_images(size: int, seed: int = 0) -> dict[str, np.ndarray]:
    """[3, size, size] images in [0, 1] that networks rarely see: constant black, white and 1e-8,
    a one-pixel checkerboard, saturated noise."""
    rng = np.random.default_rng(seed)
    i, j = np.indices((size, size))
    return {"black": np.zeros((3, size, size)), "white": np.ones((3, size, size)),
            "constant 1e-8": np.full((3, size, size), 1e-8),
            "one-pixel checkerboard": np.broadcast_to((i + j) % 2, (3, size, size)).astype(np.float64),
            "saturated noise": (rng.uniform(size=(3, size, size)) > 0.5).astype(np.float64)}


def _randomised(model, seed: int = 0, std: float = 0.05):
    """``model`` with every parameter moved by N(0, std): untrained zero-initialised layers pass their
    input through unchanged, which would hide the arithmetic under test."""
    import torch

    gen = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for p in model.parameters():
            p.add_(std * torch.randn(p.shape, generator=gen))
    return model.eval()


def model_rows(size: int = 64) -> list[dict]:
    """The Refiner (default config, tex+geo) and the Examiner (examiner_nano), randomised weights, in float32
    against the same weights in float64 on extreme images. Error: max abs difference of the refined
    images, of the scores."""
    import copy

    import torch

    from trioman.toolkit.examiner import create_examiner, examiner_config
    from trioman.toolkit.refiner import create_refiner

    refiner = _randomised(create_refiner())
    examiner_cfg = examiner_config("examiner_nano")
    examiner = _randomised(create_examiner(examiner_cfg))
    rows = []
    for name, (model, side, views) in {"Refiner (tex+geo)": (refiner, size, 3),
                                       "Examiner (examiner_nano)": (examiner, examiner_cfg.img_size, 2)}.items():
        model64 = copy.deepcopy(model).double()
        for label, image in extreme_images(side).items():
            x = torch.from_numpy(np.ascontiguousarray(image))[None]
            with torch.no_grad():
                y32 = model(*[x.float()] * views)
                y64 = model64(*[x] * views)
            y32, y64 = (np.asarray(y.detach().numpy() if hasattr(y, "detach") else y, np.float64) for y in (y32, y64))
            rows.append(_row("Refiner and Examiner, float32 vs float64", f"{name}, {label}", "torch float32",
                             np.abs(y32 - y64).max(), np.isfinite(y32).all(),
                             f"{side}x{side}, output range [{y32.min():.3g}, {y32.max():.3g}]"))
    return rows


def _expm(aa: np.ndarray) -> np.ndarray:
    from scipy.linalg import expm

    x, y, z = aa
    return expm(np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]]))


def rotation_rows() -> list[dict]:
    import torch

    from trioman.runtime.rotations import axis_angle_to_matrix as aa_numpy
    from trioman.toolkit.rotations import axis_angle_to_matrix as aa_torch

    axis = np.array([0.48, -0.6, 0.64])
    axis /= np.linalg.norm(axis)
    rows = []
    for label, angle in ANGLES.items():
        aa = axis * angle
        ref = _expm(aa)
        results = {"numpy float64": aa_numpy(aa), "numpy float32": aa_numpy(aa.astype(np.float32)),
                   "torch float32": aa_torch(torch.from_numpy(aa.astype(np.float32))).numpy()}
        for method, R in results.items():
            R = np.asarray(R, np.float64)
            ortho = np.abs(R @ R.T - np.eye(3)).max()
            rows.append(_row("axis-angle -> matrix vs expm", f"angle {label}", method, np.abs(R - ref).max(),
                             np.isfinite(R).all(), f"|R R^T - I| {ortho:.1e}"))
    return rows


def fk_rows(joints: int = 6) -> list[dict]:
    import torch

    from trioman.runtime.skeleton import Skeleton
    from trioman.toolkit.body.skinning import skinning_transforms

    rest = np.c_[np.zeros(joints), np.zeros(joints), 0.3 * np.arange(joints)] + [0.1, -0.2, 0.9]
    parents = np.arange(joints) - 1
    skeleton = Skeleton(tuple(f"j{i}" for i in range(joints)), parents, rest)
    rng = np.random.default_rng(0)
    axes = rng.normal(size=(joints, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    trans = np.array([0.2, 0.1, -0.3])
    rows = []
    for label, angle in ANGLES.items():
        pose = axes * angle
        G = np.eye(4)
        ref = []
        for j in range(joints):  # the chain composed from float64 matrix exponentials
            local = np.eye(4)
            local[:3, :3] = _expm(pose[j])
            local[:3, 3] = rest[j] + trans if j == 0 else rest[j] - rest[j - 1]
            G = G @ local
            A = G.copy()
            A[:3, 3] -= G[:3, :3] @ rest[j]
            ref.append(A)
        ref = np.stack(ref)
        results = {"numpy float64": skeleton.skinning_transforms(pose, trans)}
        for dtype, name in ((torch.float32, "torch float32"), (torch.float64, "torch float64")):
            results[name] = skinning_transforms(list(parents), torch.tensor(rest, dtype=dtype),
                                                torch.tensor(pose, dtype=dtype)[None],
                                                torch.tensor(trans, dtype=dtype)[None])[0].numpy()
        for method, A in results.items():
            A = np.asarray(A, np.float64)
            rows.append(_row(f"FK + LBS, a chain of {joints} joints, vs expm", f"every joint at angle {label}", method,
                             np.abs(A - ref).max(), np.isfinite(A).all(), "rotation and translation (m) entries"))
    return rows


def training_rows(out: Path, iterations: int = 30, frames: int = 4, size: int = 32) -> list[dict]:
    import csv
    import dataclasses
    import shutil

    from trioman.bench.frames import write_subject
    from trioman.toolkit.train.config import preset

    subject = out / "stability_subject"
    if not (subject / "subject.json").exists():
        shutil.rmtree(subject, ignore_errors=True)
        write_subject(subject, frames, size)
    rows = []
    for factor in (1, 100):
        from trioman.toolkit.train.loop import train

        cfg = preset("quick", iterations=iterations, checkpoint_every=iterations)
        cfg = dataclasses.replace(cfg, lr=cfg.lr * factor, point_color_lr=cfg.point_color_lr * factor)
        run = out / f"stability_train_lr_x{factor}"
        shutil.rmtree(run, ignore_errors=True)
        note = ""
        try:
            train(subject, run, cfg, progress=False)
            ended = True
        except FloatingPointError as err:
            ended, note = False, str(err).splitlines()[0]
        with (run / "train_log.csv").open() as f:
            losses = np.array([float(r["loss"]) for r in csv.DictReader(f)])
        finite = ended and losses.size > 0 and bool(np.isfinite(losses).all())
        worst = float(np.nanmax(np.where(np.isfinite(losses), losses, np.nan))) if np.isfinite(losses).any() else math.inf
        rows.append(_row("avatar training loop", f"learning rates x{factor} ({cfg.lr:g})", "torch float32", worst, finite,
                         note or f"{losses.size} steps logged, last loss {losses[-1]:.4f}" if losses.size else note))
    return rows


def bench_stability(args: argparse.Namespace) -> dict:
    """The report of ``trioman bench stability``."""
    import torch

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    seeds = args.seeds or 2
    rows = renderer_rows(seeds) + gradient_rows(seeds) + model_rows() + rotation_rows() + fk_rows() + training_rows(out, iterations=args.iterations or 30)
    return {"target": "stability", "machine": machine(), "torch_threads": torch.get_num_threads(), "rows": rows,
            "all_finite": all(r["finite"] for r in rows)}


def stability_markdown(r: dict) -> str:
    lines = ["# trioman bench stability", "", f"Machine: {r['machine']}; torch uses {r['torch_threads']} threads.",
             "Worst error: max abs difference against the float64 reference of the group (renderers: RGB and alpha; "
             "rotations and FK: matrix entries, translations in metres); training: the largest logged loss.", ""]
    group = None
    for row in r["rows"]:
        if row["group"] != group:
            group = row["group"]
            lines += ["", f"## {group}", "", "| case | method | worst error | finite | note |", "|---|---|---|---|---|"]
        lines.append(f"| {row['case']} | {row['method']} | {row['worst_error']:.2e} | "
                     f"{'yes' if row['finite'] else '**no**'} | {row['note']} |")
    lines += ["", f"Every output finite: {'yes' if r['all_finite'] else 'no'}.", ""]
    return "\n".join(lines)
