"""``trioman bench models``: the Refiner and Examiner trained on a synthetic corpus and evaluated on
held-out subjects' test frames (novel poses and views), as in the paper (``bench_models``).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import torch

from trioman.bench.common import batched, best_time, mean_metrics
from trioman.bench.config import ModelsBenchConfig
from trioman.toolkit.corpus.build import CORPUS_JSON, CorpusConfig, build_corpus, triplet_paths
from trioman.toolkit.examiner import auroc, pair_auroc
from trioman.toolkit.corpus.training import (
    FitConfig,
    examiner_batch,
    fit_examiner,
    fit_refiner,
    nchw,
    refiner_batch,
)
from trioman.toolkit.refiner import CONDITIONS, refiner_inputs
from trioman.toolkit.corpus.triplets import TripletSet


def bench_models(config: ModelsBenchConfig) -> dict:
    """The report of ``trioman bench models``:

    - Refiner, for conditions none / tex / tex+geo (the paper's Table 2) and warp / warp+geo: PSNR/SSIM (masked protocol and
      unmasked) of the coarse render and of the refined coarse view against the GT. The texture reference
      of a test frame is the training frame that sees the body from the closest direction.
    - Examiner: AUROC of real (I^T, reference) against coarse (I_c^T, reference) pairs, with two
      references: the nearest-view training frame (as for the Refiner; another pose and sequence) and a
      real frame T+k of the same sequence (the paper's pairs); and the density of its scores for GT
      frames and for frames refined under each condition (the paper's Examiner figure).
    - Wall time of each training run and inference time per frame.

    The corpus is built first when absent (``trioman synth-corpus``); trained models are reused when
    their run folder is complete, so a rerun only evaluates.
    """
    corpus = Path(config.corpus)
    ccfg = CorpusConfig(train_subjects=config.subjects, heldout_subjects=config.heldout, size=config.size)
    variants = list(config.baseline_frames)
    if not (corpus / CORPUS_JSON).is_file():
        build_corpus(corpus, ccfg)
    for v in variants:  # coarse frames from baselines trained on a subset: built on demand
        if v != "all":
            build_corpus(corpus, dataclasses.replace(ccfg, baseline_frames=v))
    out = Path(config.out)
    runs = out / "runs"
    fit = FitConfig(steps=config.refiner_steps, batch=config.batch, crop=config.crop)
    backbone = {"backbone": config.backbone, "pretrained": None if config.pretrained is None else str(config.pretrained)}
    tag = "" if backbone["backbone"] == "scratch" else "_" + backbone["backbone"].replace("-", "_")  # its own run folders
    refiners, infos = {}, {}
    for cond in CONDITIONS:
        refiners[cond], infos[f"refiner_{cond}"] = fit_refiner(corpus, runs / f"refiner_{cond.replace('+', '_')}{tag}", cond, fit,
                                                               config.refiner_size, **backbone)
    for v in variants:
        if v != "all":
            key = f"refiner_tex+geo_{v}"
            refiners[key], infos[key] = fit_refiner(corpus, runs / f"refiner_tex_geo_{v}{tag}", "tex+geo",
                                                    dataclasses.replace(fit, baseline_frames=v), config.refiner_size, **backbone)
    examiner, infos["examiner"] = fit_examiner(corpus, runs / "examiner", config.examiner,
                                               FitConfig(steps=config.examiner_steps, batch=config.batch, lr=3e-4, crop=None))

    test = TripletSet.load(triplet_paths(corpus)["heldout"]).evaluation("test")
    tb = refiner_batch(test)
    gt, coarse, ref, mask = tb.target, tb.coarse, tb.reference, nchw(test.mask[..., None])
    rows = {"coarse": mean_metrics(coarse, gt, mask)}
    refined = {}
    for key, model in refiners.items():
        cond = model.config.conditions
        reference = refiner_inputs(tb, cond)[1] if model.config.views > 1 else ref  # warp*: the aligned reference
        refined[key] = batched(lambda c, r, n: model(c, r, n)[:, 0], coarse, reference, tb.normal)
        label = cond if key in CONDITIONS else f"{cond}, baselines on a {key.rsplit('_', 1)[1]} of frames"
        rows[f"refined ({label})"] = mean_metrics(refined[key], gt, mask)

    score = lambda cand: batched(examiner, cand, ref).numpy()  # noqa: E731
    scores = {"GT": score(gt), "coarse": score(coarse), **{f"refined ({c})": score(refined[c]) for c in CONDITIONS}}
    labels = np.r_[np.ones(len(gt)), np.zeros(len(gt))]
    auc = auroc(torch.from_numpy(np.r_[scores["GT"], scores["coarse"]]), torch.from_numpy(labels))
    near = examiner_batch(TripletSet.load(triplet_paths(corpus)["heldout"]).nearby("test", FitConfig().k_max))
    auc_near = pair_auroc(examiner, near.gt, near.coarse, near.reference, batch=8)

    one = refiner_batch(test._replace(**{k: getattr(test, k)[:1] for k in test._fields}))
    with torch.no_grad():
        timing = {f"refiner_{c}_ms": 1000 * best_time(lambda: refiners[c](*refiner_inputs(one, c)), 5) for c in CONDITIONS}
        timing["examiner_ms"] = 1000 * best_time(lambda: examiner(one.coarse, one.reference), 5)
    figure = out / "examiner_scores.png"
    _density_plot(scores, figure)
    return {"corpus": str(corpus), "heldout_test_frames": len(gt), "size": int(gt.shape[-1]), "metrics": rows,
            "examiner_auroc_real_vs_coarse": float(auc), "examiner_auroc_real_vs_coarse_nearby": float(auc_near), "score_mean": {k: float(v.mean()) for k, v in scores.items()},
            "training": {k: {"seconds": v["seconds"], "steps": v["fit"]["steps"], "final_loss": v["final_loss"]}
                         for k, v in infos.items()},
            "examiner_selection": {k: infos["examiner"].get(k) for k in ("selected_step", "validation_auroc")},
            "inference": timing, "figure": str(figure), "threads": torch.get_num_threads(), "refiner_backbone": backbone["backbone"]}


def _density_plot(scores: dict[str, np.ndarray], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    xs = np.linspace(0, 1, 201)
    fig, ax = plt.subplots(figsize=(6, 3.5), dpi=120)
    for name, s in scores.items():
        bw = max(0.02, 1.06 * float(np.std(s)) * len(s) ** -0.2)  # Silverman's rule, floored
        dens = np.exp(-0.5 * ((xs[:, None] - s[None]) / bw) ** 2).sum(1) / (len(s) * bw * np.sqrt(2 * np.pi))
        ax.plot(xs, dens, label=f"{name} (mean {s.mean():.2f})")
    ax.set_xlabel("Examiner score against the reference frame")
    ax.set_ylabel("density")
    ax.set_title("Examiner scores on held-out test frames")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def models_markdown(r: dict) -> str:
    lines = [
        f"# trioman bench models ({r['size']}x{r['size']}, {r['heldout_test_frames']} held-out test frames)", "",
        f"Corpus: `{r['corpus']}`. Masked protocol: GT mask on both images, white background.", "",
        "| images vs GT | PSNR | SSIM | PSNR unmasked | SSIM unmasked |", "|---|---|---|---|---|",
    ]
    for name, m in r["metrics"].items():
        lines.append(f"| {name} | {m['psnr']:.2f} | {m['ssim']:.4f} | {m['psnr_unmasked']:.2f} | {m['ssim_unmasked']:.4f} |")
    lines += ["", "Examiner AUROC, real vs coarse frames of the held-out test frames, against a reference:", "",
              f"- the nearest-view training frame (another pose and sequence): **{r['examiner_auroc_real_vs_coarse']:.3f}**",
              f"- a real frame T+k of the same sequence, 0 < |k| <= 4 (the paper's pairs): "
              f"**{r['examiner_auroc_real_vs_coarse_nearby']:.3f}**", ""]
    sel = r.get("examiner_selection") or {}
    if sel.get("selected_step") is not None:
        vals = ", ".join(f"{k}: {v:.3f}" for k, v in sel["validation_auroc"].items())
        lines += [f"Examiner weights of step {sel['selected_step']}, the best AUROC on the held-out training subject "
                  f"(validation, the paper's pairs on all its frames; by step: {vals}).", ""]
    lines += ["| Examiner score mean | " + " | ".join(r["score_mean"]) + " |",
              "|---|" + "---|" * len(r["score_mean"]),
              "| | " + " | ".join(f"{v:.3f}" for v in r["score_mean"].values()) + " |", "",
              f"![Examiner score densities]({Path(r['figure']).name})", "",
              "| training run | steps | wall time | final loss |", "|---|---|---|---|"]
    for name, t in r["training"].items():
        lines.append(f"| {name} | {t['steps']} | {t['seconds'] / 60:.1f} min | {t['final_loss']:.4f} |")
    lines += ["", "| inference, batch 1 | ms |", "|---|---|"]
    lines += [f"| {k[:-3]} | {v:.1f} |" for k, v in r["inference"].items()]
    return "\n".join(lines) + "\n"
