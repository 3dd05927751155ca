"""The ablation's report: the summary over subjects and seeds with the targets' verdicts, the figures (PSNR bars,
the same test frames across variants) and the markdown."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from trioman.bench.ablation.measure import FUSED_TEXTURE
from trioman.bench.ablation_config import ALL_VARIANTS
from trioman.runtime.image_io import write_png
from trioman.runtime.preview import contact_sheet
from trioman.toolkit.evaluate import load_run, render_frame

LABELS = {
    "baseline": "Baseline", "baseline_long": "Baseline, equal steps (control)", "G": "+ Generator",
    "GR_none": "+ Refinement (without condition)", "GR_tex": "+ Refinement (only tex. condition)",
    "GR_tex+geo": "+ Generator & Refiner (tex.&geo.)", "GR_warp+geo": "+ Generator & Refiner (aligned ref.&geo.)",
    "GRk_warp+geo": "+ Generator & Refiner (aligned ref.&geo.), carried pixels kept",
    "GRE": "+ Generator & Refiner (aligned ref.&geo., carried pixels kept) & Examiner",
    "GRd_tex+geo": "+ Generator & Refiner (tex.&geo.), detail only (lever)",
    "aligned": "+ Generator, aligned real pixels (no Refiner)",
    "ceiling_seen": "Ceiling of what the capture saw: the truth only where real pixels were carried",
    "ceiling": "Ceiling: the truth at every draw",
}
# The paper's subject 00028 (PSNR dB): Table 1 against the baseline, Table 2 against coarse frames.
PAPER_TABLE1 = {"baseline": 30.5842, "G": 31.2905, "GR_tex+geo": 32.6586, "GRE": 33.0412}
PAPER_TABLE2 = {"G": 31.2905, "GR_none": 30.9897, "GR_tex": 32.1369, "GR_tex+geo": 32.6586}


def _mean_over_seeds(runs: dict[str, dict], key: str) -> float:
    return float(np.mean([r[key] for r in runs.values()]))


def summarise(results: dict[str, dict]) -> dict:
    """Per variant: the mean over subjects of the seed means (PSNR, SSIM, ...); the baseline's, the control's
    and GRE's seed spreads (max - min per subject, averaged); the targets' verdicts: the full system's gain over
    the baseline against twice the larger of its and the baseline's spreads, and its gain over the equal-steps
    control against twice the larger of its and the control's."""
    keys = ("psnr", "ssim", "lpips", "psnr_unmasked", "ssim_unmasked")
    subjects = list(results)
    variants = [v for v, *_ in ALL_VARIANTS if all(v in results[s] for s in subjects)]
    mean = {v: {k: (float(np.mean([_mean_over_seeds(results[s][v], k) for s in subjects]))
                    if all(r[k] is not None for s in subjects for r in results[s][v].values()) else None) for k in keys}
            for v in variants}
    spread = {v: float(np.mean([np.ptp([r["psnr"] for r in results[s][v].values()]) for s in subjects]))
              for v in ("baseline", "baseline_long", "GRE") if v in variants and all(len(results[s][v]) > 1 for s in subjects)}
    p = {v: mean[v]["psnr"] for v in variants}
    verdict = {}
    if {"baseline", "GRE"} <= set(p):
        gain = p["GRE"] - p["baseline"]
        verdict["full_gain_db"] = gain
        verdict["full_gain_at_least_1db"] = gain >= 1.0
        pair = [spread[v] for v in ("baseline", "GRE") if v in spread]
        if pair:  # one seed per run: no spread to compare with
            verdict["gain_exceeds_twice_seed_spread"] = gain > 2 * max(pair)
    if {"baseline_long", "GRE"} <= set(p):
        verdict["control_gain_db"] = p["GRE"] - p["baseline_long"]
        pair = [spread[v] for v in ("baseline_long", "GRE") if v in spread]
        if "baseline_long" in spread:
            verdict["control_gain_exceeds_twice_seed_spread"] = verdict["control_gain_db"] > 2 * max(pair)
    if {"baseline", "G", "GR_tex+geo", "GRE"} <= set(p):
        verdict["table1_order_holds"] = p["baseline"] < p["G"] < p["GR_tex+geo"] < p["GRE"]
    if {"baseline", "GR_warp+geo", "GRE", "ceiling"} <= set(p):
        verdict["warp_order_holds"] = p["baseline"] < p["GR_warp+geo"] < p["GRE"] < p["ceiling"]
    if {"GR_none", "GR_tex", "GR_tex+geo"} <= set(p):
        verdict["table2_order_holds"] = p["GR_none"] < p["GR_tex"] < p["GR_tex+geo"]
    share = share_of_ceiling(mean)
    if {"baseline_long", "ceiling"} <= set(p):
        verdict["ceiling_gain_db"] = p["ceiling"] - p["baseline_long"]
        verdict["ceiling_gain_at_least_1db"] = verdict["ceiling_gain_db"] >= 1.0
        if "GRE" in share:
            verdict["full_share_of_ceiling"] = share["GRE"]
            verdict["full_recovers_85_percent"] = share["GRE"] >= 0.85
        if {"GRE", "ceiling_seen"} <= set(share) and abs(share["ceiling_seen"]) > 1e-9:
            verdict["seen_share_of_ceiling"] = share["ceiling_seen"]
            verdict["full_share_of_seen_ceiling"] = share["GRE"] / share["ceiling_seen"]
    if "baseline" in mean and mean["baseline"]["psnr_unmasked"] is not None:
        base = mean["baseline"]["psnr_unmasked"]
        verdict["unmasked_at_least_baseline"] = {v: mean[v]["psnr_unmasked"] >= base for v in variants
                                                 if v not in ("baseline", "baseline_long") and mean[v]["psnr_unmasked"] is not None}
    return {"mean": mean, "seed_spread_psnr": spread, "share_of_ceiling": share, "verdict": verdict}


def variant_grid(out: Path, name: str, runs: list[tuple[str, Path]], frames: int = 3) -> Path:
    """The same test frames across the (variant, seed-0 run) ``runs``: rows = frames, columns = GT + variants."""
    images, labels = [], []
    loaded = [(v, load_run(r)[0]) for v, r in runs]
    _, subj, _, _ = load_run(runs[0][1])
    idx = subj.indices("test")
    for i in idx[np.linspace(0, len(idx) - 1, frames).astype(int)]:
        mask = subj.mask(int(i))
        images.append(subj.image(int(i)) + (1 - mask)[..., None])
        labels.append(f"GT {subj.frame_names[i]}")
        for v, model in loaded:
            images.append(render_frame(model, subj, int(i)))
            labels.append(v)
    path = out / f"grid_{name}.png"
    write_png(path, contact_sheet(images, labels, cols=1 + len(loaded)))
    return path


def bar_charts(report: dict, out: Path) -> None:
    # here, not at the top: the Agg backend is picked before pyplot loads, only when a chart is drawn
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    for name, res in report["results"].items():
        variants = [v for v, *_ in ALL_VARIANTS if v in res]
        means = [_mean_over_seeds(res[v], "psnr") for v in variants]
        errs = [np.ptp([r["psnr"] for r in res[v].values()]) / 2 for v in variants]
        fig, ax = plt.subplots(figsize=(7, 3.6), dpi=120)
        ax.bar(range(len(variants)), means, yerr=errs, capsize=3, color="#4c72b0")
        ax.set_xticks(range(len(variants)), variants, rotation=20, fontsize=8)
        lo = min(means) - 1.0
        ax.set_ylim(lo, max(means) + 0.5)
        ax.set_ylabel("test PSNR (dB, masked)")
        ax.set_title(f"Ablation, held-out subject {name} (bars: half the seed range)")
        ax.grid(axis="y", alpha=0.3)
        fig.tight_layout()
        fig.savefig(out / f"ablation_{name}.png")
        plt.close(fig)


def _frame_target(frames: dict[str, float]) -> list[str]:
    """The frame-level target (Refiner warp+geo, carried pixels kept >= aligned >= render + 1.5 dB), with and without
    the fused texture, for the kinds a report holds."""
    out = []
    for how, suffix in (("", ""), (f" with the fused texture {FUSED_TEXTURE}", f", fused texture {FUSED_TEXTURE}")):
        a = frames.get(f"aligned{suffix} (no Refiner)")
        r = frames.get(f"refined (warp+geo), carried pixels kept{suffix}")
        if a is None or r is None:
            continue
        holds = r >= a >= frames["coarse"] + 1.5
        out.append(f"Frame-level target{how}: refined (warp+geo, carried pixels kept) {r:.2f} >= aligned {a:.2f} >= "
                   f"render + 1.5 dB ({frames['coarse'] + 1.5:.2f}): {'holds' if holds else 'does not hold'}.")
    return out


def _row(label: str, m: dict, ref: float | None, paper: float | None, share: float | None = None) -> str:
    d = "" if ref is None else f"{m['psnr'] - ref:+.2f}"
    lp = "n/a" if m.get("lpips") is None else f"{m['lpips']:.4f}"
    sh = "" if share is None else f"{share:.0%}"
    return (f"| {label} | {m['psnr']:.2f} | {m['ssim']:.4f} | {lp} | {m['psnr_unmasked']:.2f} | {d} | {sh} | "
            f"{'' if paper is None else f'{paper:+.2f}'} |")


def share_of_ceiling(per_variant: dict[str, dict]) -> dict[str, float]:
    """Per augmented variant: (its PSNR - the equal-steps control's) / (the ceiling's - the control's)."""
    if not {"baseline_long", "ceiling"} <= set(per_variant):
        return {}
    gain = per_variant["ceiling"]["psnr"] - per_variant["baseline_long"]["psnr"]
    if abs(gain) < 1e-9:
        return {}
    return {v: (m["psnr"] - per_variant["baseline_long"]["psnr"]) / gain for v, m in per_variant.items()
            if v not in ("baseline", "baseline_long", "ceiling")}


def _tables(per_variant: dict[str, dict]) -> list[str]:
    head = ["| method | PSNR | SSIM | LPIPS | PSNR unmasked | ours vs first row (dB) | share of the ceiling's gain | "
            "paper 00028 vs first row (dB) |", "|---|---|---|---|---|---|---|---|"]
    share = share_of_ceiling(per_variant)
    lines = ["Table 1 (share of the ceiling's gain: over the equal-steps control)", ""] + head
    base = per_variant["baseline"]["psnr"] if "baseline" in per_variant else None
    for v in ("baseline", "baseline_long", "G", "aligned", "GR_tex+geo", "GR_warp+geo", "GRk_warp+geo", "GRE", "GRd_tex+geo",
              "ceiling_seen", "ceiling"):
        if v in per_variant:
            paper = PAPER_TABLE1[v] - PAPER_TABLE1["baseline"] if v in PAPER_TABLE1 else None
            lines.append(_row(LABELS[v], per_variant[v], base, paper, share.get(v)))
    if "G" in per_variant:
        lines += ["", "Table 2", ""] + head
        coarse = per_variant["G"]["psnr"]
        for v in ("G", "GR_none", "GR_tex", "GR_tex+geo"):
            if v in per_variant:
                label = "Coarse image generation (+ Generator)" if v == "G" else LABELS[v].replace(
                    "+ Generator & Refiner (tex.&geo.)", "+ Refinement (tex.&geo. condition)")
                lines.append(_row(label, per_variant[v], coarse, PAPER_TABLE2[v] - PAPER_TABLE2["G"], share.get(v)))
    return lines + [""]


def ablation_markdown(r: dict) -> str:
    plan = r["plan"]
    lines = [f"# trioman bench ablation ({len(r['subjects'])} held-out subjects: {', '.join(r['subjects'])})", "",
             f"Machine: {r.get('machine', 'n/a')}. Corpus `{r['corpus']}`; the Refiners and the Examiner were trained on its "
             f"training subjects only, on the coarse frames of the '{r.get('baseline_frames', 'all')}' variant (all: their "
             "avatars saw every frame; subset: every 4th, so most coarse frames carry novel-view error). Test split = novel poses from novel views; PSNR/SSIM under the masked protocol "
             f"(GT mask, white background). LPIPS: {'AlexNet' if r['lpips'] else 'not computed (no local weights)'}.", "",
             f"Capture regime: {plan.get('coverage', 1.0):g} of a full turn in the training frames, "
             + ("poses fitted by `trioman fit` from each subject's video (every frame; a phone's focal prior; "
                + (f"the video's long side {plan['video_side']} px, tracked and fitted at that size, the subject at the corpus's"
                   if plan.get("video_side") else "the video at the subject's size") + "), the test "
                "frames' too, evaluated at their fitted poses refitted to each test frame's pixels with the avatar frozen "
                "(`trioman eval --poses optimised`); the ceiling rows: the truth at the draws' pose change and camera "
                "move, applied to the true frame" if plan.get("poses") == "fit" else
                f"pose noise {plan.get('pose_noise', 0.0):g} deg" + (" (evaluated at the true test poses)" if plan.get("pose_noise") else ""))
             + (f"; the Generator's camera sigmas x{plan['reach']:g}" if plan.get("reach", 1.0) != 1.0 else "")
             + f"; pseudo frames masked by '{plan.get('mask', 'alpha')}'. "
             f"Baseline: {plan['iterations']} steps (quick preset). Augmented runs and the control: "
             f"{plan['augmented_iterations']} steps; pseudo-GT from step {plan['start']:.0%} on, pool of {plan['pool']} "
             f"rebuilt every {plan['refresh']} steps, {plan['share']:.0%} of later steps on it, weight {plan['weight']}. "
             f"Seeds 0..{plan['seeds'] - 1} for the baseline, the control and the full system (seed means in the tables)."
             + (f" Lever GRd_tex+geo: the tex+geo Refiner's pseudo-GT keeping only its detail (its change minus that change "
                f"blurred by {plan['detail_sigma']} px)." if plan.get("detail_sigma") else ""), ""]
    if r.get("missing_runs"):
        lines += [f"Report of the finished runs only (--no-training); not yet trained: {', '.join(r['missing_runs'])}. "
                  "A variant missing for a subject is left out of the mean.", ""]
    s = r["summary"]
    lines += ["## Mean over subjects", ""] + _tables(s["mean"])
    v = s["verdict"]
    if "full_gain_db" in v:
        lines += [f"Full system vs baseline: **{v['full_gain_db']:+.2f} dB** (target >= +1.0 dB: "
                  f"{'met' if v['full_gain_at_least_1db'] else 'missed'})"
                  + ("; seed spread (max - min, mean over subjects): "
                     + ", ".join(f"{k} {x:.2f} dB" for k, x in s["seed_spread_psnr"].items())
                     + f"; gain > 2 x spread: {'yes' if v['gain_exceeds_twice_seed_spread'] else 'no'}."
                     if "gain_exceeds_twice_seed_spread" in v else "; one seed per run, no seed spread.")]
    if "control_gain_exceeds_twice_seed_spread" in v:
        lines.append(f"Full system vs the equal-steps control: **{v['control_gain_db']:+.2f} dB**; gain > 2 x the larger of "
                     f"the control's and the full system's seed spreads: "
                     f"{'yes' if v['control_gain_exceeds_twice_seed_spread'] else 'no'}.")
    for key, text in (("table1_order_holds", "baseline < + G < + G&R (tex+geo) < + G&R&E"),
                      ("warp_order_holds", "baseline < + G&R (warp+geo) < + G&R&E < ceiling"),
                      ("table2_order_holds", "none < tex < tex+geo")):
        if key in v:
            lines.append(f"Ordering {text}: {'holds' if v[key] else 'does not hold'}.")
    if "ceiling_gain_db" in v:
        lines.append(f"Ceiling (the truth at every draw) over the equal-steps control: **{v['ceiling_gain_db']:+.2f} dB** "
                     f"(target >= +1.0 dB: {'met' if v['ceiling_gain_at_least_1db'] else 'missed'})"
                     + (f"; the full system recovers {v['full_share_of_ceiling']:.0%} of it (target >= 85 %)."
                        if "full_share_of_ceiling" in v else "."))
    if "full_share_of_seen_ceiling" in v:
        lines.append(f"The truth only where a training frame saw the surface (the body pixels no frame saw left unsupervised) "
                     f"reaches {v['seen_share_of_ceiling']:.0%} of the ceiling's gain; the full system recovers "
                     f"{v['full_share_of_seen_ceiling']:.0%} of that seen-surface ceiling's gain.")
    if v.get("unmasked_at_least_baseline"):
        below = [k for k, ok in v["unmasked_at_least_baseline"].items() if not ok]
        lines.append("Unmasked PSNR of every augmented row >= the baseline's: "
                     + ("yes." if not below else f"no ({', '.join(below)} below)."))
    lines.append("")
    if r.get("fit"):
        lines += ["## The fitted poses against the truth", "", "`trioman fit` on each subject's video (toolkit/fit/evaluate.compare; "
                  "joints in each camera's frame, mm).", "",
                  "| subject | frames fitted | PA-MPJPE | on the test frames | arms / legs / head | MPJPE | person mask IoU |",
                  "|---|---|---|---|---|---|---|"]
        for name, f in r["fit"].items():
            if f:
                lines.append(f"| {name} | {f['frames']} | {f['pa_mpjpe']} | {f['pa_mpjpe_test']} | {f['pa_arms']} / "
                             f"{f['pa_legs']} / {f['pa_head']} | {f['mpjpe']} | {f['mask_iou']} |")
        lines.append("")
    for name, res in r["results"].items():
        per = {var: {k: _mean_over_seeds(runs, k) if all(x[k] is not None for x in runs.values()) else None
                     for k in ("psnr", "ssim", "lpips", "psnr_unmasked")} for var, runs in res.items()}
        lines += [f"## Subject {name}", ""] + _tables(per)
        lines += ["| run | seed | steps | test PSNR | training time | pseudo steps | kept / candidates | "
                  "ms per step: generate / render / normal / refine / examine |", "|---|---|---|---|---|---|---|---|"]
        for var, runs in res.items():
            for seed, x in runs.items():
                a = x["augment"]
                ms = " / ".join(f"{a['ms_per_step'][k]:.1f}" for k in ("generate", "render", "normal", "refine", "examine")) if a else ""
                kept = f"{a['kept']} / {a['candidates']}" if a else ""
                lines.append(f"| {var} | {seed} | {x['iterations']} | {x['psnr']:.2f} | {x['train_seconds'] / 60:.1f} min | "
                             f"{a['pseudo_steps'] if a else ''} | {kept} | {ms} |")
        lines += ["", f"![PSNR per variant](ablation_{name}.png)", "", f"![the same test frames across variants](grid_{name}.png)", "",
                  f"![the same draws: truth, the baseline avatar's render, aligned, refined per condition](pseudo_gt_{name}.png)", ""]
    for name, t in r.get("pseudo_gt_truth", {}).items():
        if not t:
            continue
        lines += [f"## Pseudo-GT against the truth: {name}", "",
                  f"{t['draws']} Generator draws from training frames; truth = the synthetic subject rendered by its own mesh "
                  "renderer at the draw's pose change on the true pose and camera; masked PSNR. Pseudo-GT from the seed-0 "
                  "baseline avatar by the shared augmentation step; coverage = share of body pixels holding carried real pixels:",
                  "", "| pseudo-GT | PSNR vs truth | vs the render | coverage | ms per draw |", "|---|---|---|---|---|"]
        lines += [f"| {k} | {v:.2f} | {v - t['frames']['coarse']:+.2f} | "
                  f"{'' if k not in t.get('coverage', {}) else format(t['coverage'][k], '.0%')} | "
                  f"{t.get('ms_per_draw', {}).get(k, float('nan')):.0f} |" for k, v in t["frames"].items()]
        lines += [""] + _frame_target(t["frames"])
        o = t.get("off_body")
        if o and o["psnr"]:
            lines += ["", f"The person beyond the body (hair, loose clothes: true person pixels the body mesh at the draw "
                      f"does not cover) is **{o['share']:.0%}** of the person's pixels. Which masks reach it (recall: the "
                      "share of those pixels a mask holds; spill: what a mask adds outside the person, as a share of the "
                      "person's pixels) and each pseudo-GT's PSNR on those pixels alone:", "",
                      "| mask | recall beyond the body | spill |", "|---|---|---|"]
            lines += [f"| {k} | {'n/a' if m['recall'] is None else format(m['recall'], '.0%')} | {m['spill']:.1%} |"
                      for k, m in o["masks"].items()]
            lines += ["", "| pseudo-GT | PSNR beyond the body |", "|---|---|"]
            lines += [f"| {k} | {v:.2f} |" for k, v in o["psnr"].items()]
        lines += ["", "Each finished run's own renders at the same draws (what its next pseudo-GT would start from), with "
                  "the mean signed colour error inside the body (RGB, 0..1):", "",
                  "| run (seed 0) | PSNR vs truth | colour error R, G, B |", "|---|---|---|"]
        lines += [f"| {LABELS[v]} | {a['psnr']:.2f} | {', '.join(f'{b:+.4f}' for b in a['colour_bias'])} |"
                  for v, a in t["avatars"].items()]
        lines += [""]
        e = t.get("examiner")
        if e:
            lines += [f"What the Examiner keeps (the GRE step: two candidates per source frame, refined by the warp+geo "
                      f"Refiner, from the baseline avatar; {e['pairs']} pairs): it picks the candidate closer to the truth in "
                      f"**{e['agreement']:.0%}** of pairs (50 %: no better than a coin).", "",
                      "| candidate | PSNR vs truth | camera change (deg) | pose change (deg, summed) |", "|---|---|---|---|",
                      f"| kept | {e['psnr_chosen']:.2f} | {e['view_chosen']:.1f} | {e['pose_chosen']:.1f} |",
                      f"| dropped | {e['psnr_other']:.2f} | {e['view_other']:.1f} | {e['pose_other']:.1f} |", ""]
    lines += ["## Do the Refiners use their conditions?", "",
              "Masked PSNR of held-out test triplets (coarse render at the test pose; tex+geo: the nearest-view training "
              "frame as reference; warp+geo: real pixels of other training frames carried to the test pose, "
              "toolkit/corpus/triplets.py):", "", "| input | tex+geo | warp+geo |", "|---|---|---|"]
    checks = r["condition_check"]
    checks = {"tex+geo": checks} if "true" in checks else checks  # reports written before warp+geo hold one check

    def cell(c: str, key: str) -> str:
        x = checks.get(c, {}).get(key)
        return "" if x is None else f"{x:.2f}" + ("" if key in ("coarse", "true", "aligned") else f" ({x - checks[c]['true']:+.2f})")

    for key, text in (("coarse", "coarse (no refinement)"), ("aligned", "aligned reference alone (no Refiner)"),
                      ("true", "refined, true reference and normal map"),
                      ("without_reference", "refined without the reference (tex+geo: another subject's frame; "
                                            "warp+geo: nothing carried)"),
                      ("other_subject_reference", "refined, another subject's reference"),
                      ("zero_normal", "refined, zero normal map")):
        if any(key in c for c in checks.values()):
            lines.append(f"| {text} | {cell('tex+geo', key)} | {cell('warp+geo', key)} |")
    lines += ["", "| model | steps | training time |", "|---|---|---|"]
    lines += [f"| {k} | {m['steps']} | {m['seconds'] / 60:.1f} min |" for k, m in r["models"].items()]
    lines += ["", f"Whole benchmark: {r['wall_seconds'] / 60:.1f} min wall time (finished runs reused); "
              f"peak resident memory {r.get('peak_rss_mib', 0):.0f} MiB.", ""]
    return "\n".join(lines)
