"""``bench_ablation``: the whole ``trioman bench ablation`` target, from the corpus to the report's numbers."""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import torch

from trioman.bench.ablation.jobs import run_job, train_in_parallel
from trioman.bench.ablation.measure import condition_check, evaluated, pseudo_gt_truth
from trioman.bench.ablation.models import train_models, trained_models
from trioman.bench.ablation.plan import needed_models, plan_jobs, run_iterations, variant_runs
from trioman.bench.ablation.report import bar_charts, summarise, variant_grid
from trioman.bench.ablation.subjects import fit_error, regime_subject
from trioman.bench.ablation_config import AblationBenchConfig
from trioman.toolkit.corpus.build import CORPUS_JSON, CorpusConfig, build_corpus, finished, triplet_paths
from trioman.toolkit.lpips import load_lpips_or_say_why


def bench_ablation(config: AblationBenchConfig) -> dict:
    corpus, out = Path(config.corpus), Path(config.out)
    if not (corpus / CORPUS_JSON).is_file():
        build_corpus(corpus, CorpusConfig(train_subjects=config.subjects, heldout_subjects=config.heldout, size=config.size,
                                          baseline_frames=config.baseline_frames, style=config.style))
    meta = json.loads((corpus / CORPUS_JSON).read_text())
    heldout = [s["name"] for s in meta["subjects"] if s["role"] == "heldout"]
    names = list(config.ablation_subjects) if config.ablation_subjects else heldout
    unknown = sorted(set(names) - set(heldout))
    if unknown:
        raise ValueError(f"ablation_subjects: {unknown} are not held-out subjects of {corpus} (held out: {heldout})")
    plan = config.plan
    only = set(config.variants) if config.variants else None
    known = {v for v, *_ in plan.variants}
    if only is not None and not only <= known:
        raise ValueError(f"variants: unknown {sorted(only - known)}; the plan's rows are {[v for v, *_ in plan.variants]}")
    t0 = time.perf_counter()
    report_only = not config.training
    keys = needed_models(sorted(only) if only is not None else list(known))
    models, model_info = trained_models(out) if report_only else train_models(corpus, out, config, keys)
    print(f"bench ablation: Refiners and Examiner ready ({time.perf_counter() - t0:.0f} s)", flush=True)
    missing: list[str] = []
    lpips = load_lpips_or_say_why("bench ablation")
    results: dict[str, dict] = {}
    truth: dict[str, dict] = {}
    # noisy poses: at the true test poses; fitted: each test frame's fitted pose refitted to its pixels with the avatar
    # frozen (test-time pose optimisation, the protocol of fitted captures), so the rows differ by their avatars
    poses = "true" if plan.pose_noise > 0 else "optimised" if plan.poses == "fit" else "stored"
    subjects = {h: regime_subject(corpus / "subjects" / h, out, plan) for h in names}
    if not report_only:
        threads = max(1, (os.cpu_count() or 1) // config.jobs) if config.jobs > 1 else torch.get_num_threads()
        todo = plan_jobs(plan, out, subjects, models, only, threads)
        if config.jobs > 1:
            train_in_parallel(todo, config.jobs, lpips is not None)
        else:
            for k, job in enumerate(todo, 1):
                run_job(job, lpips)
                print(f"bench ablation: {'warmed up' if job.stop_after else 'trained'} {job.run.parent.name}/{job.run.name} "
                      f"({k}/{len(todo)}, {time.perf_counter() - t0:.0f} s so far)", flush=True)
    for heldout_name in names:
        name = heldout_name + plan.regime
        subject = subjects[heldout_name]
        results[name] = {}
        for variant, seed in variant_runs(plan):
            t = time.perf_counter()
            run = plan.run(out, heldout_name, variant, seed)
            if not finished(run, run_iterations(variant, plan)):
                missing.append(f"{run.parent.name}/{run.name}")
                continue
            r = evaluated(run, run_iterations(variant, plan), lpips, poses)
            results[name].setdefault(variant, {})[str(seed)] = r
            print(f"bench ablation: {name} {variant} seed {seed}: test PSNR {r['psnr']:.2f} dB "
                  f"({r['train_seconds']:.0f} s training, {time.perf_counter() - t:.0f} s with evaluation)", flush=True)
        done = [v for v, *_ in plan.variants if "0" in results[name].get(v, {})]
        if done:
            variant_grid(out, name, [(v, plan.run(out, heldout_name, v)) for v in done])
        if "baseline" in done:  # pseudo-GT is made from the baseline avatar
            truth[name] = pseudo_gt_truth(subject, lambda v, h=heldout_name: plan.run(out, h, v), models, plan, out, name)
    trips = [triplet_paths(corpus, config.baseline_frames)["heldout"][heldout.index(n)] for n in names]
    check = {c: condition_check(models[f"refiner_{c}"], trips, c) for c in ("tex+geo", "warp+geo")
             if f"refiner_{c}" in models}
    report = {"corpus": str(corpus), "subjects": [n + plan.regime for n in names], "baseline_frames": config.baseline_frames, "plan": plan.record(),
              "results": results, "models": model_info, "condition_check": check, "pseudo_gt_truth": truth, "wall_seconds": time.perf_counter() - t0,
              "lpips": lpips is not None, "missing_runs": missing}
    if plan.poses == "fit":
        report["fit"] = {h + plan.regime: fit_error(subjects[h]) for h in names}
    report["summary"] = summarise(results)
    bar_charts(report, out)
    return report
