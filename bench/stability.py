"""``trioman bench stability``: the numerical-stability checks as one report (``bench_stability``): renderers,
gradients, rotations and FK + LBS, the Refiner and Examiner and their ONNX files, the training loops.
"""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Any, Callable, NamedTuple

import numpy as np

from trioman.bench.common import machine
from trioman.bench.config import StabilityBenchConfig

KEYS = ("means", "quats", "scales", "opacities", "colors", "viewmat", "K")
ANGLES = {"pi - 1e-3": math.pi - 1e-3, "pi - 1e-6": math.pi - 1e-6, "pi": math.pi, "pi + 1e-6": math.pi + 1e-6,
          "1e-4": 1e-4, "1e-8": 1e-8, "1e-12": 1e-12, "0": 0.0}
MODEL_SIZE = 32  # px, the tiny Refiner's and Examiner's input side
LR_FACTORS = (1, 100)  # the training cases' learning rates, times each loop's default


def _row(group: str, case: str, method: str, error: float, finite: bool | None, note: str = "", **extra: Any) -> dict:
    """One report row; ``finite`` None: nothing was run (the note says why)."""
    return {"group": group, "case": case, "method": method, "worst_error": float(error),
            "finite": None if finite is None else bool(finite), "note": note, **extra}


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
    from trioman.runtime.render.reference import rasterize_reference
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
    """[3, size, size] images in [0, 1] that networks rarely see: constant black, white and 1e-8, uniform
    noise, one bright pixel on black, a one-pixel checkerboard, saturated noise (each channel 0 or 1) and
    saturated colour bars (the eight corners of the RGB cube)."""
    rng = np.random.default_rng(seed)
    i, j = np.indices((size, size))
    pixel = np.zeros((3, size, size))
    pixel[:, size // 2, size // 2] = 1.0
    corners = ((np.arange(8)[:, None] >> np.arange(3)) & 1).astype(np.float64)  # [8, 3]
    return {"black": np.zeros((3, size, size)), "white": np.ones((3, size, size)),
            "constant 1e-8": np.full((3, size, size), 1e-8),
            "uniform noise": rng.uniform(size=(3, size, size)),
            "one bright pixel": pixel,
            "one-pixel checkerboard": np.broadcast_to((i + j) % 2, (3, size, size)).astype(np.float64),
            "saturated noise": (rng.uniform(size=(3, size, size)) > 0.5).astype(np.float64),
            "saturated colour bars": np.ascontiguousarray(corners[j * 8 // size].transpose(2, 0, 1))}


def tiny_models() -> tuple[Any, Any]:
    """(Refiner, Examiner) at MODEL_SIZE px, initialised from seed 0: a tex+geo Refiner with a 2-level U-Net
    (widths 8..32) and an Examiner of examiner_nano's layout."""
    import torch

    from trioman.toolkit.examiner import create_examiner, examiner_config
    from trioman.toolkit.refiner import RefinerConfig, create_refiner

    refiner = RefinerConfig(image_size=MODEL_SIZE, latent_channels=4, latent_downsample=2, vae_widths=(8, 16),
                            unet_widths=(16, 32), attention_heads=2, norm_groups=4, conditions="tex+geo")
    with torch.random.fork_rng(devices=[]):  # the Examiner draws from the global RNG; keep it
        torch.manual_seed(0)
        return create_refiner(refiner, seed=0), create_examiner(examiner_config("examiner_nano", img_size=MODEL_SIZE))


def _randomised(model, seed: int = 0, std: float = 0.05):
    """``model`` with every parameter moved by N(0, std): untrained zero-initialised layers pass their
    input through unchanged, which would hide the arithmetic under test."""
    import torch

    gen = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for p in model.parameters():
            p.add_(std * torch.randn(p.shape, generator=gen))
    return model.eval()


def _max_diff(a: np.ndarray, b: np.ndarray) -> float:
    """max |a - b| in float64; inf when either holds a NaN or Inf."""
    d = np.abs(np.asarray(a, np.float64) - np.asarray(b, np.float64))
    return float(d.max()) if np.isfinite(d).all() else math.inf


def model_rows(out: Path) -> list[dict]:
    """The tiny Refiner and Examiner (randomised weights) on the extreme images: torch float32 against
    float64, one row per image; then their ONNX variants (``onnx_rows``, exported into out/stability_onnx)."""
    import copy

    import torch

    refiner, examiner = tiny_models()
    models = {"Refiner (tex+geo)": (_randomised(refiner), 3), "Examiner (examiner_nano layout)": (_randomised(examiner), 2)}
    images = extreme_images(MODEL_SIZE)
    rows = []
    for name, (model, views) in models.items():
        model64 = copy.deepcopy(model).double()
        for label, image in images.items():
            x = torch.from_numpy(np.ascontiguousarray(image))[None]
            with torch.no_grad():
                y32 = model(*[x.float()] * views).numpy()
                y64 = model64(*[x] * views).numpy()
            rows.append(_row("Refiner and Examiner, float32 vs float64", f"{name}, {label}", "torch float32",
                             _max_diff(y32, y64), np.isfinite(y32).all(),
                             f"{MODEL_SIZE}x{MODEL_SIZE}, output range [{y32.min():.3g}, {y32.max():.3g}]"))
    return rows + onnx_rows(models, images, out / "stability_onnx")


def onnx_rows(models: dict[str, tuple[Any, int]], images: dict[str, np.ndarray], folder: Path) -> list[dict]:
    """The Refiner and the Examiner (``models``: name -> (torch module, inputs), in that order) exported by
    ``export_onnx`` (fp32, fp16, int8; synthetic calibration and gate frames) into ``folder`` and run by the
    runtime on each of ``images`` alone (batch 1: dynamic int8 quantizes each batch with its own range).
    One row per model and variant: fp32 against torch float32, fp16 and int8 against fp32, the worst
    image named. A variant its export gate rejected gets a row saying so."""
    import torch

    from trioman.export.onnx_models import VARIANTS, export_onnx, file_name
    from trioman.runtime.onnx_models import load_model

    (refiner, _), (examiner, _) = models.values()
    report = export_onnx(refiner=refiner, examiner=examiner, out=folder, variants=VARIANTS, size=MODEL_SIZE,
                         overwrite=True, calibration_frames=2, gate_frames=2)
    group = "Refiner and Examiner, ONNX variants on extreme images"
    rows = []
    for (name, (model, views)), kind in zip(models.items(), ("refiner", "examiner")):
        xs = [np.ascontiguousarray(image, np.float32)[None] for image in images.values()]
        with torch.no_grad():
            outputs = {"torch float32": [model(*[torch.from_numpy(x)] * views).numpy() for x in xs]}
        for precision in VARIANTS:  # fp32 first: the reference of fp16 and int8
            method = f"onnxruntime {precision} vs {'torch float32' if precision == 'fp32' else 'fp32'}"
            if file_name(kind, precision) not in report["files"]:
                gate = report["rejected"][file_name(kind, precision)]["gate"]
                rows.append(_row(group, name, method, math.nan, None, f"not exported: rejected by its gate ({gate})"))
                continue
            session = load_model(folder / file_name(kind, precision), kind)
            ys = outputs[f"onnxruntime {precision}"] = [session.run(*[x] * views) for x in xs]
            ref = outputs["torch float32" if precision == "fp32" else "onnxruntime fp32"]
            errors = [_max_diff(y, r) for y, r in zip(ys, ref)]
            worst = int(np.argmax(errors))
            y = np.concatenate([np.ravel(v) for v in ys])
            rows.append(_row(group, name, method, errors[worst], np.isfinite(y).all(),
                             f"worst on {list(images)[worst]}; {len(xs)} images at {MODEL_SIZE}x{MODEL_SIZE}, "
                             f"outputs in [{np.nanmin(y):.3g}, {np.nanmax(y):.3g}]"))
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


class LoopOutcome(NamedTuple):
    """How one training run went (``loop_outcome``)."""

    result: Any  # what the loop returned; None when it stopped
    stopped: str  # the message of a run that stopped ("" when it ended)
    skipped: int  # steps the non-finite guard skipped
    weights_finite: bool  # the weights after the last step that ran are finite


_SKIPPED_IN_ALL = re.compile(r"\((\d+) skipped in all\)")  # the guard's stop message (toolkit/loops/guard.py)


def loop_outcome(train: Callable[[], Any], run: Path) -> LoopOutcome:
    """Run ``train()``, a training loop that checkpoints into ``run`` after every step, and read how it went.

    Every checkpoint holds the guard's count of skipped steps and is refused (NonFiniteError) when the
    weights are not finite. So: a run that ended had finite weights and its last checkpoint's count; a
    run the guard stopped (its message counts the skipped steps "in all") kept the finite weights of its
    last update; a refused checkpoint means non-finite weights, and the step that made them updated, so
    the previous checkpoint's count is the run's."""
    from trioman.toolkit.loops.checkpoint import latest_checkpoint, load_checkpoint
    from trioman.toolkit.loops.guard import NonFiniteError

    def counted() -> int:
        ckpt = latest_checkpoint(run)
        return 0 if ckpt is None else int(load_checkpoint(ckpt).get("skipped", 0))

    try:
        result = train()
    except NonFiniteError as err:
        message = str(err)
        by_guard = _SKIPPED_IN_ALL.search(message)
        if by_guard:
            return LoopOutcome(None, message, int(by_guard.group(1)), True)
        return LoopOutcome(None, message, counted(), False)
    return LoopOutcome(result, "", counted(), True)


def _training_row(loop: str, factor: int, lr: float, outcome: LoopOutcome, losses: list[float]) -> dict:
    finite = [v for v in losses if math.isfinite(v)]
    how = f"stopped: {outcome.stopped.splitlines()[0]}" if outcome.stopped else f"ended; last loss {finite[-1]:.4f}" if finite else "ended"
    return _row("training loops at 1x and 100x the default learning rate", f"{loop}, learning rate x{factor} ({lr:g})",
                "torch float32", max(finite) if finite else math.nan, outcome.weights_finite,
                f"{len(losses)} losses, {outcome.skipped} steps skipped by the guard; {how}",
                skipped=outcome.skipped, stopped=outcome.stopped)


def avatar_training_rows(out: Path, iterations: int, frames: int = 4, size: int = 32) -> list[dict]:
    """The avatar loop (quick preset, every learning rate scaled) on a small generated subject. Losses:
    the train log's."""
    import csv
    import dataclasses
    from trioman.bench.frames import write_subject
    from trioman.runtime.outputs import remove_own
    from trioman.toolkit.train.config import preset
    from trioman.toolkit.train.loop import RUN_FOLDER, train

    subject = out / "stability_subject"
    if not (subject / "subject.json").exists():  # written whole or not at all (save_subject); never over a foreign folder
        write_subject(subject, frames, size)
    rows = []
    for factor in LR_FACTORS:
        cfg = preset("quick", iterations=iterations, checkpoint_every=1)
        cfg = dataclasses.replace(cfg, lr=cfg.lr * factor, point_color_lr=cfg.point_color_lr * factor)
        run = out / f"stability_train_lr_x{factor}"
        remove_own(run, RUN_FOLDER)
        outcome = loop_outcome(lambda cfg=cfg, run=run: train(subject, run, cfg, progress=False), run)
        with (run / "train_log.csv").open() as f:
            losses = [float(r["loss"]) for r in csv.DictReader(f)]
        rows.append(_training_row("avatar", factor, cfg.lr, outcome, losses))
    return rows


def model_training_rows(out: Path, iterations: int, batch: int = 4) -> list[dict]:
    """The Refiner and the Examiner loops on the tiny models and synthetic frames (one fixed batch).
    Losses: those the loop returns (none when it stopped)."""
    import dataclasses
    from trioman.export.onnx_models import synthetic_frames
    from trioman.runtime.outputs import remove_own
    from trioman.toolkit.loops.checkpoint import LOOP_RUN
    from trioman.toolkit.examiner import ExaminerTrainConfig, examiner_loop
    from trioman.toolkit.corpus.training import examiner_batch, refiner_batch
    from trioman.toolkit.refiner import RefinerTrainConfig, refiner_loop

    frames = synthetic_frames(batch, (MODEL_SIZE, MODEL_SIZE), seed=0)
    loops = {
        "Refiner": (RefinerTrainConfig(steps=iterations, checkpoint_every=1),
                    lambda cfg, run: refiner_loop(tiny_models()[0], lambda step: refiner_batch(frames), cfg, run)),
        "Examiner": (ExaminerTrainConfig(steps=iterations, checkpoint_every=1),
                     lambda cfg, run: examiner_loop(tiny_models()[1], [examiner_batch(frames)], cfg, run)),
    }
    rows = []
    for loop, (default, fit) in loops.items():
        for factor in LR_FACTORS:
            cfg = dataclasses.replace(default, lr=default.lr * factor)
            run = out / f"stability_train_{loop.lower()}_lr_x{factor}"
            remove_own(run, LOOP_RUN)
            outcome = loop_outcome(lambda fit=fit, cfg=cfg, run=run: fit(cfg, run), run)
            rows.append(_training_row(loop, factor, cfg.lr, outcome, [] if outcome.result is None else outcome.result.losses))
    return rows


def bench_stability(config: StabilityBenchConfig) -> dict:
    """The report of ``trioman bench stability``: a row per case with its worst error and whether every output
    stayed finite.

    - Renderers: the numpy runtime renderer and the torch rasterizer (float32) against the float64 oracle
      (trioman.runtime.render.reference) on extreme scenes: scales 1e-6..1e2 m with anisotropy 1e6, huge
      faint Gaussians and needles from 5 cm in front of the camera (``bench.scenes.extreme_scene``), half the
      Gaussians behind the camera, opacities at 1/255 and at 1, and a scene 1e4 times larger seen from 1e4
      times farther. Error: max abs difference of RGB and alpha over the image.
    - Refiner and Examiner: tiny models (``tiny_models``: the arithmetic, not the capacity, is under test)
      with randomised weights on extreme images (constant black, white and 1e-8, uniform noise, one bright
      pixel, a one-pixel checkerboard, saturated noise, saturated colour bars): the torch models in float32
      against float64, and their ONNX variants as ``trioman export onnx`` writes them (fp32, fp16, int8) run
      by the runtime, fp32 against torch float32 and fp16/int8 against fp32. Error: max abs difference of
      the refined images, of the scores.
    - Rotations and FK + LBS: axis-angle -> matrix (numpy float64 and float32, torch float32) against scipy's
      matrix exponential in float64 at angles near pi, at pi and tiny; the skinning transforms of a chain of
      joints all rotated by those angles (numpy and torch) against the chain composed from the exponentials.
      Error: max abs difference of the matrix entries (and of the translations, metres, for FK).
    - Training: the avatar loop (quick preset, a small generated subject), the Refiner and the Examiner
      loops (the tiny models, synthetic frames) at their default learning rates and at 100x them, with a
      checkpoint every step. Error: the largest finite loss of the steps that updated; finite: the weights
      stayed finite; each row also counts the steps the non-finite guard skipped and gives the message of a
      run that stopped (docs/design.md, "Conventions": training loops).
    ``config.iterations`` is the training cases' steps and ``config.seeds`` the extreme scenes drawn.
    """
    import torch

    out = Path(config.out)
    out.mkdir(parents=True, exist_ok=True)
    seeds, iterations = config.seeds, config.iterations
    rows = (renderer_rows(seeds) + gradient_rows(seeds) + model_rows(out) + rotation_rows() + fk_rows()
            + avatar_training_rows(out, iterations) + model_training_rows(out, iterations))
    return {"target": "stability", "machine": machine(), "torch_threads": torch.get_num_threads(), "rows": rows,
            "all_finite": all(r["finite"] is not False for r in rows)}


def stability_markdown(r: dict) -> str:
    lines = ["# trioman bench stability", "", f"Machine: {r['machine']}; torch uses {r['torch_threads']} threads.",
             "Worst error: max abs difference against the reference of the group (renderers: the float64 oracle, RGB "
             "and alpha; rotations and FK: matrix entries, translations in metres; Refiner and Examiner: refined images "
             "and scores); training: the largest finite loss, finite: the weights.", ""]
    group = None
    for row in r["rows"]:
        if row["group"] != group:
            group = row["group"]
            lines += ["", f"## {group}", "", "| case | method | worst error | finite | note |", "|---|---|---|---|---|"]
        finite = "n/a" if row["finite"] is None else "yes" if row["finite"] else "**no**"
        lines.append(f"| {row['case']} | {row['method']} | {row['worst_error']:.2e} | {finite} | {row['note']} |")
    lines += ["", f"Every output finite: {'yes' if r['all_finite'] else 'no'}.", ""]
    return "\n".join(lines)
