"""The ablation's measurements: a run's test metrics, whether the Refiners use their conditions, and, on a
synthetic subject, pseudo-GT frames against the truth and what the Examiner keeps."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

from trioman.bench.ablation_config import AblationPlan
from trioman.bench.common import batched, mean_metrics
from trioman.runtime.aligned import AlignConfig, Aligner, SourceViews
from trioman.runtime.formats import load_subject
from trioman.runtime.generator import sample
from trioman.runtime.image_io import write_png
from trioman.runtime.metrics import psnr as psnr_db
from trioman.runtime.outputs import atomic_path
from trioman.runtime.preview import contact_sheet
from trioman.runtime.pseudo_gt import PseudoConfig, Source, make_pseudo_frames
from trioman.toolkit.evaluate import evaluate, load_run, poses_key
from trioman.toolkit.loops.checkpoint import latest_checkpoint
from trioman.toolkit.corpus.training import nchw, refiner_batch
from trioman.toolkit.refiner import load_refiner
from trioman.toolkit.synth.subject import TruthRenderer
from trioman.toolkit.train.augment_config import AugmentConfig
from trioman.toolkit.train.augmentation import render_candidate
from trioman.toolkit.train.loop import AUGMENT_JSON
from trioman.toolkit.train.augment_models import load_pseudo_examiner, load_pseudo_refiner
from trioman.toolkit.corpus.triplets import TripletSet

FUSED_TEXTURE = 256  # texels a side of the fused texture's row in the frame-level table (AlignConfig.texture)


def evaluated(run: Path, iterations: int, lpips, poses: str = "stored") -> dict:
    """A finished run's test metrics (evaluated once), training time and augmentation record."""
    summary_file = run / "eval_test" / "summary.json"
    summary = json.loads(summary_file.read_text()) if summary_file.is_file() else None
    if summary is None or summary["step"] != iterations or summary.get("poses_key") != poses_key(poses):
        summary = evaluate(run, "test", lpips=lpips, progress=False, video=False, grid_frames=3, poses=poses)
    seconds = float((run / "train_log.csv").read_text().splitlines()[-1].split(",")[1])
    aug = json.loads((run / AUGMENT_JSON).read_text()) if (run / AUGMENT_JSON).is_file() else None
    return {"iterations": iterations, "train_seconds": seconds, **summary["mean"], "augment": aug}


@torch.no_grad()
def condition_check(refiner_run: Path, heldout: list[Path], conditions: str = "tex+geo") -> dict[str, float]:
    """Masked PSNR of refinement (``conditions`` tex+geo or warp+geo) on held-out test triplets with the true
    conditions; without the reference (tex+geo: another subject's frame; warp+geo: nothing carried, the coarse
    render as the aligned reference); with a zero normal map (a Refiner that uses a condition loses PSNR)."""
    model = load_refiner(latest_checkpoint(refiner_run))
    test = TripletSet.load(heldout).evaluation("test")
    tb = refiner_batch(test)
    mask = nchw(test.mask[..., None])
    warp = conditions == "warp+geo"
    true_ref = tb.aligned if warp else tb.reference
    other = tb.coarse if warp else torch.roll(tb.reference, shifts=len(tb.reference) // len(heldout), dims=0)

    def psnr(reference: torch.Tensor, normal: torch.Tensor) -> float:
        out = batched(lambda c, r, n: model(c, r, n)[:, 0], tb.coarse, reference, normal)
        return mean_metrics(out, tb.target, mask)["psnr"]

    found = {"coarse": mean_metrics(tb.coarse, tb.target, mask)["psnr"], "true": psnr(true_ref, tb.normal),
             "without_reference": psnr(other, tb.normal), "zero_normal": psnr(true_ref, torch.zeros_like(tb.normal))}
    if warp:
        found["aligned"] = mean_metrics(tb.aligned, tb.target, mask)["psnr"]
    return found


@torch.no_grad()
def pseudo_gt_truth(subject: Path, run_of: Callable[[str], Path], models: dict[str, Path], plan: AblationPlan, out: Path, name: str,
                    draws: int = 12, seed: int = 7) -> dict:
    """Pseudo-GT against the truth, which a synthetic subject has: the same ``draws`` Generator candidates
    (from training frames, at the plan's reach; ``run_of(variant)``: its seed-0 run) made into pseudo-GT by the shared augmentation step (runtime.pseudo_gt) from the
    seed-0 baseline avatar, one kind at a time (each Refiner in ``models``), against the subject's own mesh renderer at the draw (the
    candidate's pose change on the true pose, its camera). Writes pseudo_gt_<name>.png (rows: draws; columns:
    truth, render, aligned, each Refiner) and pseudo_gt_<name>.npz, the frames the table scores (float32): "truth"
    [D, H, W, 3] on black, "mask" [D, H, W] (the true mask), "labels" [kinds] and "frames" [kinds, D, H, W, 3] over the
    background. -> {"frames": masked PSNR per kind, "coverage": mean share of body
    pixels holding carried real pixels, "ms_per_draw": per kind, "avatars": per finished run (seed 0) masked PSNR
    of its render and its mean signed colour error (RGB, inside the true mask), "off_body": the true person pixels
    beyond the body mesh at the draw (hair, loose clothes): their share of the person, how much of them the carried
    mask and the avatar's alpha cover (recall) and how much either adds outside the person (spill, a share of the
    person's pixels), and each kind's PSNR on them alone}."""
    subj = load_subject(subject)
    try:
        truth_renderer = TruthRenderer(subj)
    except ValueError:
        return {}
    rng = np.random.default_rng(seed)
    W, H, bg = subj.width, subj.height, subj.background.astype(np.float32)
    train = subj.indices("train")
    aligner = Aligner(subj.body, SourceViews.of_subject(subj, train))
    fused = Aligner(subj.body, aligner.views, AlignConfig(texture=FUSED_TEXTURE))
    picked = []
    for p in rng.choice(len(train), size=draws):
        i = int(train[p])
        c = sample(subj.body.skeleton, np.asarray(subj.poses[i]), np.asarray(subj.trans[i]), np.asarray(subj.viewmat[i]),
                   rng, 1, AugmentConfig(camera=plan.camera).generator())[0]
        src = _source(subj, int(p), i, bg)
        picked.append((c, src, truth_renderer.at_draw(i, c, src.K)))
    truth = np.stack([t[0] for _, _, t in picked])
    mask = np.stack([t[1] for _, _, t in picked])[..., None]

    def psnr(x: np.ndarray) -> float:
        # both over white outside the true mask (the masked protocol); one PSNR of all draws together
        return float(psnr_db((x * mask)[None], (truth * mask)[None])[0])

    def render_with(model, K: np.ndarray):
        return lambda c: render_candidate(model, c, torch.from_numpy(K.astype(np.float32)), W, H, bg)

    base = load_run(run_of("baseline"))[0]
    kinds = [("coarse", PseudoConfig("coarse"), None), ("aligned (no Refiner)", PseudoConfig("aligned"), None),
             (f"aligned, fused texture {FUSED_TEXTURE} (no Refiner)", PseudoConfig("aligned"), None)]
    kinds += [(f"refined ({c})", PseudoConfig("refined"), load_pseudo_refiner(str(models[f"refiner_{c}"])))
              for c in ("none", "tex", "tex+geo", "warp", "warp+geo") if f"refiner_{c}" in models]
    if "refiner_warp+geo" in models:
        warp = next(r for label, _, r in kinds if label == "refined (warp+geo)")
        kinds += [("refined (warp+geo), carried pixels kept", PseudoConfig("refined", keep_carried=True), warp),
                  (f"refined (warp+geo), carried pixels kept, fused texture {FUSED_TEXTURE}",
                   PseudoConfig("refined", keep_carried=True), warp)]
    if plan.detail_sigma and "refiner_tex+geo" in models:
        kinds.append((f"detail only (tex+geo, {plan.detail_sigma:g} px)", PseudoConfig("refined", detail_sigma=plan.detail_sigma),
                      next(r for label, _, r in kinds if label == "refined (tex+geo)")))
    # The person beyond the body (hair, loose clothes): true person pixels the body mesh at the draw does not cover
    drawn = [aligner.align(src.position, c.pose, c.trans, c.viewmat, src.K) for c, src, _ in picked]
    inside = mask[..., 0] > 0.5
    off = inside & ~np.stack([a.body for a in drawn])
    alphas = np.stack([render_with(base, src.K)(c)[1] for c, src, _ in picked])
    off_body = {"share": float(off.sum() / max(1, inside.sum())),
                "masks": {name: {"recall": float((m[off] > 0.5).mean()) if off.any() else None,
                                 "spill": float(((m > 0.5) & ~inside).sum() / max(1, inside.sum()))}
                          for name, m in (("carried", np.stack([a.silhouette for a in drawn])), ("alpha", alphas))},
                "psnr": {}}
    frames, coverage, ms, columns = {}, {}, {}, {}
    for label, cfg, refiner in kinds:
        seconds: dict[str, float] = {}
        made = [make_pseudo_frames([c], src, render_with(base, src.K), cfg, body=subj.body,
                                   aligner=fused if "fused texture" in label else aligner,
                                   refiner=refiner, seconds=seconds) for c, src, _ in picked]
        images = np.stack([m.images[0] for m in made])  # over the subject's background; composited like the truth
        frames[label] = psnr(images)
        if off.any():  # on the off-body pixels alone, against the truth over the same background
            want = truth + (1 - mask) * bg
            off_body["psnr"][label] = float(psnr_db(images[off][None, None], want[off][None, None])[0])
        ms[label] = 1e3 * sum(seconds.values()) / draws
        if made[0].coverage:
            coverage[label] = float(np.mean([m.coverage[0] for m in made]))
        columns[label] = images
    sheet, labels = [], []
    shown = min(4, draws)
    _, ys, xs = np.nonzero(mask[:shown, ..., 0] > 0)  # crop to the bodies (with a margin), enlarged to see the detail
    pad = max(2, int(ys.max() - ys.min()) // 10) if len(ys) else 0
    y0, y1 = (max(0, ys.min() - pad), min(H, ys.max() + pad + 1)) if len(ys) else (0, H)
    x0, x1 = (max(0, xs.min() - pad), min(W, xs.max() + pad + 1)) if len(xs) else (0, W)
    zoom = max(1, 256 // max(y1 - y0, 1))
    for j in range(shown):
        for label, images in [("truth", truth + (1 - mask) * bg)] + list(columns.items()):
            crop = images[j][y0:y1, x0:x1]
            sheet.append(np.repeat(np.repeat(crop, zoom, 0), zoom, 1))
            labels.append(label)
    write_png(out / f"pseudo_gt_{name}.png", contact_sheet(sheet, labels, cols=1 + len(columns)))
    with atomic_path(out / f"pseudo_gt_{name}.npz") as tmp:
        np.savez_compressed(tmp, truth=truth.astype(np.float32), mask=mask[..., 0].astype(np.float32),
                            labels=np.array(list(columns)), frames=np.stack(list(columns.values())).astype(np.float32))
    avatars = {}
    for v, *_ in plan.variants:
        run = run_of(v)
        if (run / "eval_test" / "summary.json").is_file():
            model = load_run(run)[0]
            x = np.stack([render_with(model, src.K)(c)[0] for c, src, _ in picked])
            inside = mask[..., 0] > 0.5
            avatars[v] = {"psnr": psnr(x), "colour_bias": [float(b) for b in (x - truth)[inside].mean(0)]}
    found = {"draws": draws, "frames": frames, "coverage": coverage, "ms_per_draw": ms, "avatars": avatars, "off_body": off_body}
    if "examiner" in models and "refiner_warp+geo" in models:
        found["examiner"] = examiner_choices(subj, base, models, truth_renderer, aligner, draws, seed, plan.camera)
    return found


def _source(subj, position: int, i: int, bg: np.ndarray):
    """Training frame ``i`` (``position`` among the training frames) over ``bg``: the shared step's source frame."""
    m = subj.mask(i)[..., None]
    return Source(position, (subj.image(i) * m + (1 - m) * bg).astype(np.float32), np.asarray(subj.K[i], np.float64), bg)


def _view_change(a: np.ndarray, b: np.ndarray) -> float:
    """The angle (degrees) between two world->camera rotations."""
    r = np.asarray(a, np.float64)[:3, :3] @ np.asarray(b, np.float64)[:3, :3].T
    return float(np.degrees(np.arccos(np.clip((np.trace(r) - 1) / 2, -1.0, 1.0))))


@torch.no_grad()
def examiner_choices(subj, avatar, models: dict[str, Path], truth_renderer, aligner, draws: int, seed: int,
                     camera: tuple[float, float, float] | None = None) -> dict:
    """What the Examiner keeps (the GRE row's step): for ``draws`` training frames, two Generator candidates each,
    refined by the warp+geo Refiner with the carried pixels kept; the Examiner's pick against the truth. -> {"agreement": share of pairs where the
    pick is the candidate closer to the truth, "psnr_chosen" / "psnr_other": mean masked PSNR vs the truth,
    "view_chosen" / "view_other": mean camera change from the source frame (degrees), "pose_chosen" /
    "pose_other": mean summed joint-angle change (degrees), "score_gap": mean score difference}."""
    refiner = load_pseudo_refiner(str(models["refiner_warp+geo"]))
    examiner = load_pseudo_examiner(str(models["examiner"]))
    rng = np.random.default_rng(seed + 1)
    W, H, bg = subj.width, subj.height, subj.background.astype(np.float32)
    train = subj.indices("train")
    rows = []
    for p in rng.choice(len(train), size=draws):
        i = int(train[p])
        cands = sample(subj.body.skeleton, np.asarray(subj.poses[i]), np.asarray(subj.trans[i]),
                       np.asarray(subj.viewmat[i]), rng, 2, AugmentConfig(camera=camera).generator())
        src = _source(subj, int(p), i, bg)
        K = src.K
        made = make_pseudo_frames(cands, src, lambda c: render_candidate(avatar, c, torch.from_numpy(K.astype(np.float32)), W, H, bg),
                                  PseudoConfig("examined", keep_carried=True), body=subj.body, aligner=aligner, refiner=refiner, examiner=examiner)
        quality = []
        for k, c in enumerate(cands):
            t, tm = truth_renderer.at_draw(i, c, K)
            tm = tm[..., None]
            quality.append(float(psnr_db((made.images[k] * tm)[None], (t * tm)[None])[0]))
        rows.append((made.chosen, quality, [_view_change(c.viewmat, subj.viewmat[i]) for c in cands],
                     [float(np.degrees(np.linalg.norm(c.delta_pose, axis=-1).sum())) for c in cands], made.scores))
    pick = [(ch, 1 - ch) for ch, *_ in rows]
    return {"pairs": draws,
            "agreement": float(np.mean([q[a] >= q[b] for (a, b), (_, q, *_) in zip(pick, rows)])),
            **{f"{key}_{side}": float(np.mean([r[j][ab[s]] for ab, r in zip(pick, rows)]))
               for j, key in ((1, "psnr"), (2, "view"), (3, "pose")) for s, side in ((0, "chosen"), (1, "other"))},
            "score_gap": float(np.mean([r[4][a] - r[4][b] for (a, b), r in zip(pick, rows)]))}
