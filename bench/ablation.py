"""``trioman bench ablation``: the paper's Tables 1 and 2 on held-out synthetic subjects.

The Refiner (one per condition none / tex / tex+geo / warp / warp+geo) and the Examiner are trained on the corpus's
training subjects (``trioman synth-corpus``); the avatars are trained on the held-out subjects, which
those models never saw, and evaluated on their test split (novel poses from novel views).

Variants, per held-out subject (``VARIANTS``), all from the quick preset:

    baseline        real frames only, ``iterations`` steps (seeds 0 .. seeds-1)
    baseline_long   equal-compute control: real frames only, as many steps as an augmented run (seeds)
    G               + Generator: online pseudo-GT = the avatar's own coarse renders (--augment coarse)
    aligned         the render with real pixels carried through the body mesh, no learned model (--augment aligned)
    GR_none/tex/tex+geo   + Refiner under each of the paper's conditions (--augment refined)
    GR_warp+geo     + Refiner refining the aligned reference, with the normal map (conditions warp+geo)
    GRk_warp+geo    the same, keeping the carried real pixels: the Refiner's output only where nothing was carried
    GRE             + Refiner (warp+geo, carried pixels kept) & Examiner, best of 2 candidates (--augment examined; seeds)
    ceiling_seen    the truth only where a training frame saw the surface, unsupervised elsewhere on the body
                    (--augment truth_seen): what pseudo-GT made from the capture alone gives, with nothing invented
    ceiling         the truth at every draw: the subject's own renderer (--augment truth), what a perfect Refiner gives

Every augmented row is also reported as the share of the ceiling's gain over the control it recovers.
The plan's ``coverage`` and ``pose_noise`` re-render the held-out subjects with that share of the turn and
that fitting noise (OUT/subjects); with pose noise the avatars are evaluated at the true test poses. Its ``reach``
scales the Generator's camera sigmas (the augmented runs' folders say so; the unaugmented ones are shared).

With ``--detail-sigma S`` a lever (``LEVERS``) is trained too: GRd_tex+geo, the tex+geo Refiner's
pseudo-GT keeping only its detail (``--augment-detail-sigma S``, runtime.generator.keep_detail).

An augmented run takes ``iterations / (start + (1 - start) (1 - share))`` steps, so that it trains on
as many real frames as the baseline plus its pseudo-GT steps; ``baseline_long`` has that length.
A finished run (and its evaluation) is reused, so an interrupted benchmark resumes where it stopped. The runs of
one seed as long as an augmented run (the control and the augmented rows) fork from one shared real-frame warm-up,
the control's first ``start`` steps trained once (toolkit/train/fork.py: the same weights as from scratch, bit
for bit), so each trains that many steps fewer.

Also measured: whether the tex+geo and warp+geo Refiners use their conditions (held-out test triplets refined
with the true reference and normal map; with another subject's reference frame (tex+geo) or nothing carried,
the coarse render as the aligned reference (warp+geo); with a zero normal map).
Writes ablation.md / ablation.json, a bar chart per subject, one grid of the same test frames across
variants per subject, and the same Generator draws as pseudo-GT through each mode and Refiner.
"""

from __future__ import annotations

import dataclasses
import json
import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch

from trioman.bench.ablation_config import ALL_VARIANTS, LEVERS, AblationBenchConfig, AblationPlan
from trioman.toolkit.train.augment_config import AugmentConfig

if TYPE_CHECKING:
    from trioman.toolkit.fit.config import FitConfig
    from trioman.toolkit.train.config import TrainConfig

# AugmentConfig settings of a variant beyond its mode and Refiner condition.
FUSED_TEXTURE = 256  # texels a side of the fused texture's row in the frame-level table (AlignConfig.texture)
SETTINGS = {"GRk_warp+geo": {"keep_carried": True}, "GRE": {"keep_carried": True}}
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


def _variant_runs(plan: AblationPlan) -> list[tuple[str, int]]:
    return [(name, seed) for name, _, _, seeded in plan.variants for seed in (range(plan.seeds) if seeded else (0,))]


def _train_config(name: str, seed: int, plan: AblationPlan, models: dict[str, Path]):
    from trioman.toolkit.train.config import preset

    mode, cond = next((m, c) for n, m, c, _ in ALL_VARIANTS if n == name)
    avatar = dataclasses.replace(preset("quick").avatar, seed=seed)  # a seed draws the initial weights too
    if name == "baseline":
        return preset("quick", iterations=plan.iterations, seed=seed, avatar=avatar)
    iterations = plan.augmented_iterations
    if mode is None:
        return preset("quick", iterations=iterations, seed=seed, avatar=avatar)
    paths = {}
    if cond is not None:
        paths["refiner"] = str(models[f"refiner_{cond}"])
    if mode == "examined":
        paths["examiner"] = str(models["examiner"])
    if any(name == n for n, *_ in LEVERS):
        paths["detail_sigma"] = plan.detail_sigma
    settings = {"keep_carried": False} if mode in ("refined", "examined") else {}  # the paper's rows keep nothing
    settings.update(SETTINGS.get(name, {}))
    aug = dataclasses.replace(plan.schedule, mode=mode, camera=plan.camera, **paths, **settings)
    return preset("quick", iterations=iterations, seed=seed, avatar=avatar, augment=aug, checkpoint_every=iterations)


@dataclass(frozen=True)
class Job:
    """One avatar run to train: from scratch, or forked from ``fork`` = (warm-up run, step) when it is not
    there yet (toolkit/train/fork.py); ``stop_after``: a warm-up stops at its step."""

    subject: Path
    run: Path
    cfg: TrainConfig
    fork: tuple[Path, int] | None = None
    stop_after: int | None = None


# Relative cost of a step by augmentation mode (an augmented step also makes pseudo-GT): the order in which
# ready runs start, longest first, so the last to finish are short and no core idles long at the end.
_STEP_COST = {None: 1.0, "coarse": 1.2, "aligned": 1.2, "truth": 1.2, "truth_seen": 1.25, "refined": 1.35, "examined": 1.7}


def _cost(job: Job) -> float:
    """A run's expected time in steps: a warm-up first of all (its forks wait for it), then the longest."""
    if job.stop_after is not None:
        return float("inf")
    steps = job.cfg.iterations - (job.fork[1] if job.fork else 0)
    return steps * _STEP_COST[job.cfg.augment.mode if job.cfg.augment else None]


def run_job(job: Job, lpips=None) -> None:
    """Train ``job``'s run (resumed when it is there, forked first when it is not and ``job.fork`` says from where)."""
    from trioman.toolkit.train.fork import fork_run
    from trioman.toolkit.train.loop import train

    if job.fork is not None and not (job.run / "config.json").exists():
        fork_run(job.fork[0], job.run, job.cfg, job.fork[1])
    train(job.subject, job.run, job.cfg, resume=(job.run / "config.json").exists(), progress=False, lpips=lpips,
          stop_after=job.stop_after)


def _train_run(job: Job, threads: int, with_lpips: bool) -> None:
    """One avatar run in a worker process of ``train_in_parallel``, with ``threads`` torch threads."""
    from trioman.toolkit.lpips import load_lpips

    torch.set_num_threads(threads)
    run_job(job, load_lpips() if with_lpips else None)


def train_in_parallel(todo: list[Job], jobs: int, with_lpips: bool) -> None:
    """Train the runs ``todo`` in ``jobs`` worker processes, each with an equal share of the cores (at least one
    thread); a forked run starts once the warm-up it forks from is done (warm-ups are ``todo``'s jobs that
    stop early, started first), and of the runs ready to start the longest goes first (``_cost``); one line per
    finished run. A failed run stops the others not yet started and is raised naming its folder (the finished
    ones stay; a rerun resumes the rest)."""
    import concurrent.futures
    import multiprocessing

    threads = max(1, (os.cpu_count() or 1) // jobs)
    t = time.perf_counter()
    pending = list(todo)
    warming = {j.run for j in todo if j.stop_after is not None}
    ctx = multiprocessing.get_context("spawn")  # a fresh interpreter: no forked torch thread pools
    with concurrent.futures.ProcessPoolExecutor(jobs, mp_context=ctx) as pool:
        running: dict = {}
        done = 0

        def submit_ready() -> None:
            ready = sorted((j for j in pending if j.fork is None or j.fork[0] not in warming), key=_cost, reverse=True)
            for job in ready[: jobs - len(running)]:
                pending.remove(job)
                running[pool.submit(_train_run, job, threads, with_lpips)] = job

        submit_ready()
        while running:  # at most `jobs` runs are submitted: each start takes the longest ready run
            finished, _ = concurrent.futures.wait(running, return_when=concurrent.futures.FIRST_COMPLETED)
            for future in finished:
                job = running.pop(future)
                if future.exception() is not None:
                    pool.shutdown(wait=False, cancel_futures=True)
                    raise RuntimeError(f"bench ablation: run {job.run} failed: {future.exception()}") from future.exception()
                done += 1
                warming.discard(job.run)
                what = "warmed up" if job.stop_after is not None else "trained"
                print(f"bench ablation: {what} {job.run.parent.name}/{job.run.name} ({done}/{len(todo)}, {jobs} jobs x "
                      f"{threads} threads, {time.perf_counter() - t:.0f} s so far)", flush=True)
            submit_ready()


def plan_jobs(plan: AblationPlan, out: Path, subjects: dict[str, Path], models: dict[str, Path], only: set[str] | None,
              threads: int) -> list[Job]:
    """The runs of ``subjects`` {held-out name: regime subject folder} still to train (``only`` those variants),
    warm-ups first: the runs of one subject and seed as long as an augmented run, two or more of them not yet
    started, fork from one shared real-frame warm-up (the control's first ``start`` steps, trained once with
    ``threads`` torch threads, the count the forks train with; toolkit/train/fork.py)."""
    from trioman.toolkit.corpus import finished

    step = int(round(plan.schedule.start * plan.augmented_iterations))
    warmups, jobs = [], []
    for h, subject in subjects.items():
        runs = [(v, seed, plan.run(out, h, v, seed)) for v, seed in _variant_runs(plan) if only is None or v in only]
        runs = [(v, seed, r) for v, seed, r in runs if not finished(r, _iterations(v, plan))]
        for seed in sorted({seed for _, seed, _ in runs}):
            fresh = [r for v, s, r in runs if s == seed and _iterations(v, plan) == plan.augmented_iterations
                     and not (r / "config.json").exists()]
            warm = None
            if len(fresh) >= 2:
                warm = out / "runs" / (h + plan.capture) / f"warmup_s{seed}_{threads}t"
                if not finished(warm, step):
                    cfg = dataclasses.replace(_train_config("baseline_long", seed, plan, models), checkpoint_every=step)
                    warmups.append(Job(subject, warm, cfg, stop_after=step))
            jobs += [Job(subject, r, _train_config(v, seed, plan, models), (warm, step) if warm and r in fresh else None)
                     for v, s, r in runs if s == seed]
    return warmups + jobs


def _iterations(name: str, plan: AblationPlan) -> int:
    return plan.iterations if name == "baseline" else plan.augmented_iterations


def _evaluated(run: Path, iterations: int, lpips, poses: str = "stored") -> dict:
    """A finished run's test metrics (evaluated once), training time and augmentation record."""
    from trioman.toolkit.evaluate import evaluate
    from trioman.toolkit.train.loop import AUGMENT_JSON

    summary_file = run / "eval_test" / "summary.json"
    summary = json.loads(summary_file.read_text()) if summary_file.is_file() else None
    if summary is None or summary["step"] != iterations or summary.get("poses_key") != poses:
        summary = evaluate(run, "test", lpips=lpips, progress=False, video=False, grid_frames=3, poses=poses)
    seconds = float((run / "train_log.csv").read_text().splitlines()[-1].split(",")[1])
    aug = json.loads((run / AUGMENT_JSON).read_text()) if (run / AUGMENT_JSON).is_file() else None
    return {"iterations": iterations, "train_seconds": seconds, **summary["mean"], "augment": aug}


def needed_models(variants: list[str]) -> list[str]:
    """The models (keys "refiner_<condition>", "examiner") that training ``variants`` needs (the condition check
    covers the tex+geo and warp+geo Refiners that are there: with every row, both)."""
    conds = {c for n, _, c, _ in ALL_VARIANTS if n in variants and c is not None}
    keys = [f"refiner_{c}" for c in ("none", "tex", "tex+geo", "warp", "warp+geo") if c in conds]
    return keys + (["examiner"] if "GRE" in variants else [])


def _model_run(out: Path, key: str) -> Path:
    return out / "models" / key.replace("+", "_")


def _models(corpus: Path, out: Path, config: AblationBenchConfig, keys: list[str]) -> tuple[dict[str, Path], dict]:
    """Train (or reuse, when finished) the models ``keys`` in OUT/models; the others already there are used too."""
    from trioman.toolkit.model_training import FitConfig, fit_examiner, fit_refiner

    fit = FitConfig(steps=config.refiner_steps, batch=config.batch, crop=config.crop, baseline_frames=config.baseline_frames)
    for key in keys:
        if key == "examiner":
            fit_examiner(corpus, _model_run(out, key), config.examiner,
                         FitConfig(steps=config.examiner_steps, batch=config.batch, lr=3e-4, crop=None,
                                   baseline_frames=config.baseline_frames))
        else:
            fit_refiner(corpus, _model_run(out, key), key.removeprefix("refiner_"), fit, config.refiner_size)
    return _trained_models(out)


def _trained_models(out: Path) -> tuple[dict[str, Path], dict]:
    """The models trained in ``out/models`` (a report uses what is there), as _models returns them."""
    paths, info = {}, {}
    for key in ("refiner_none", "refiner_tex", "refiner_tex+geo", "refiner_warp", "refiner_warp+geo", "examiner"):
        run = _model_run(out, key)
        if not (run / "fit.json").is_file():
            continue
        fit = json.loads((run / "fit.json").read_text())
        paths[key], info[key] = run, {"seconds": fit["seconds"], "steps": fit["fit"]["steps"]}
    return paths, info


@torch.no_grad()
def condition_check(refiner_run: Path, heldout: list[Path], conditions: str = "tex+geo") -> dict[str, float]:
    """Masked PSNR of refinement (``conditions`` tex+geo or warp+geo) on held-out test triplets with the true
    conditions; without the reference (tex+geo: another subject's frame; warp+geo: nothing carried, the coarse
    render as the aligned reference); with a zero normal map (a Refiner that uses a condition loses PSNR)."""
    from trioman.bench.common import batched, mean_metrics
    from trioman.toolkit.model_training import nchw, refiner_batch
    from trioman.toolkit.refiner import load_refiner
    from trioman.toolkit.loops.checkpoint import latest_checkpoint
    from trioman.toolkit.triplets import TripletSet

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


def bench_ablation(config: AblationBenchConfig) -> dict:
    from trioman.toolkit.corpus import CORPUS_JSON, CorpusConfig, build_corpus, triplet_paths
    from trioman.toolkit.lpips import load_lpips_or_say_why

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
    models, model_info = _trained_models(out) if report_only else _models(corpus, out, config, keys)
    print(f"bench ablation: Refiners and Examiner ready ({time.perf_counter() - t0:.0f} s)", flush=True)
    from trioman.toolkit.corpus import finished

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
        for variant, seed in _variant_runs(plan):
            t = time.perf_counter()
            run = plan.run(out, heldout_name, variant, seed)
            if not finished(run, _iterations(variant, plan)):
                missing.append(f"{run.parent.name}/{run.name}")
                continue
            r = _evaluated(run, _iterations(variant, plan), lpips, poses)
            results[name].setdefault(variant, {})[str(seed)] = r
            print(f"bench ablation: {name} {variant} seed {seed}: test PSNR {r['psnr']:.2f} dB "
                  f"({r['train_seconds']:.0f} s training, {time.perf_counter() - t:.0f} s with evaluation)", flush=True)
        done = [v for v, *_ in plan.variants if "0" in results[name].get(v, {})]
        if done:
            _grid(out, name, [(v, plan.run(out, heldout_name, v)) for v in done])
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
    _bar_charts(report, out)
    return report


def regime_subject(subject: Path, out: Path, plan: AblationPlan, fit: FitConfig | None = None) -> Path:
    """The held-out subject as the plan's regime captures it: the corpus's own folder, or (coverage < 1, pose
    noise, fitted poses) the same synthetic subject re-rendered with them in OUT/subjects (made once). Fitted poses:
    the re-rendered subject's every frame as a video (OUT/subjects/<name>.mp4), ``trioman fit`` on it at its own size
    with a phone's focal prior (OUT/subjects/<name>_fit: fit.json, overlays), the fit linked to the truth
    (toolkit/synth/linked.py) with the truth's split: the test frames' poses are fitted too, as a user's are (and
    refitted to their pixels when evaluated).
    ``fit``: the fitter's settings (default: `trioman fit`'s)."""
    if not plan.capture:
        return subject
    from trioman.runtime.formats import load_subject
    from trioman.toolkit.synth.subject import SynthConfig, synthesize_subject

    target = out / "subjects" / (subject.name + plan.capture)
    if (target / "subject.json").is_file():
        return target
    made = dict(load_subject(subject, check_images=False).meta["generator"])
    made.pop("tool"), made.pop("version")
    cfg = SynthConfig(**{**made, "coverage": plan.coverage, "pose_noise_deg": plan.pose_noise})
    if plan.poses == "true":
        synthesize_subject(cfg, target, progress=False)
        return target
    from trioman.runtime.frame_selection import FrameSelection
    from trioman.toolkit.fit.config import FitRunConfig
    from trioman.toolkit.fit.run import fit_video
    from trioman.toolkit.synth.linked import link_fitted

    stem = out / "subjects" / (subject.name + plan.capture)
    truth_dir, video, fit_dir = stem.with_name(stem.name + "_truth"), stem.with_name(stem.name + ".mp4"), stem.with_name(stem.name + "_fit")
    if not (truth_dir / "subject.json").is_file() or not video.is_file():
        stem.parent.mkdir(parents=True, exist_ok=True)
        synthesize_subject(cfg, truth_dir, overwrite=True, progress=False, video=video, video_frames="all")
    if not (fit_dir / "subject.json").is_file():
        run = FitRunConfig(selection=FrameSelection(long_side=0), test_every=0)
        fit_video(video, fit_dir, run if fit is None else dataclasses.replace(run, fit=fit), overwrite=True,
                  progress=False, say=lambda line: print(f"bench ablation: fit {subject.name}: {line}", flush=True))
    link_fitted(load_subject(fit_dir), load_subject(truth_dir), target)
    return target


def fit_error(subject: Path) -> dict | None:
    """A fitted regime subject's pose error against its truth (toolkit/fit/evaluate.compare: MPJPE, PA-MPJPE and
    per group in mm, mask IoU; over all fitted frames, and PA-MPJPE over the test frames), or None for a subject
    of true poses."""
    from trioman.runtime.formats import load_subject
    from trioman.toolkit.fit.evaluate import compare

    fitted = subject.with_name(subject.name + "_fit")
    if not (fitted / "subject.json").is_file():
        return None
    linked = load_subject(subject, check_images=False)
    found = compare(linked, load_subject(subject.with_name(subject.name + "_truth"), check_images=False))
    test = np.asarray(found.pop("per_frame_pa_mpjpe_mm"))[linked.split == "test"]
    return {**found, "pa_mpjpe_test": round(float(test.mean()), 1) if len(test) else None}


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


def _grid(out: Path, name: str, runs: list[tuple[str, Path]], frames: int = 3) -> Path:
    """The same test frames across the (variant, seed-0 run) ``runs``: rows = frames, columns = GT + variants."""
    from trioman.runtime.image_io import write_png
    from trioman.runtime.preview import contact_sheet
    from trioman.toolkit.evaluate import load_run, render_frame

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


@torch.no_grad()
def pseudo_gt_truth(subject: Path, run_of: Callable[[str], Path], models: dict[str, Path], plan: AblationPlan, out: Path, name: str,
                    draws: int = 12, seed: int = 7) -> dict:
    """Pseudo-GT against the truth, which a synthetic subject has: the same ``draws`` Generator candidates
    (from training frames, at the plan's reach; ``run_of(variant)``: its seed-0 run) made into pseudo-GT by the shared augmentation step (runtime.pseudo_gt) from the
    seed-0 baseline avatar, one kind at a time (each Refiner in ``models``), against the subject's own mesh renderer at the draw (the
    candidate's pose change on the true pose, its camera). Writes pseudo_gt_<name>.png (rows: draws; columns:
    truth, render, aligned, each Refiner). -> {"frames": masked PSNR per kind, "coverage": mean share of body
    pixels holding carried real pixels, "ms_per_draw": per kind, "avatars": per finished run (seed 0) masked PSNR
    of its render and its mean signed colour error (RGB, inside the true mask), "off_body": the true person pixels
    beyond the body mesh at the draw (hair, loose clothes): their share of the person, how much of them the carried
    mask and the avatar's alpha cover (recall) and how much either adds outside the person (spill, a share of the
    person's pixels), and each kind's PSNR on them alone}."""
    from trioman.runtime.aligned import AlignConfig, Aligner, SourceViews
    from trioman.runtime.formats import load_subject
    from trioman.runtime.generator import sample
    from trioman.runtime.image_io import write_png
    from trioman.runtime.metrics import psnr as psnr_db
    from trioman.runtime.preview import contact_sheet
    from trioman.runtime.pseudo_gt import PseudoConfig, make_pseudo_frames
    from trioman.toolkit.evaluate import load_run
    from trioman.toolkit.synth.subject import TruthRenderer
    from trioman.toolkit.train.augmentation import render_candidate
    from trioman.toolkit.train.pseudo_models import load_pseudo_refiner

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


def _source(subj, position: int, i: int, bg: np.ndarray):
    """Training frame ``i`` (``position`` among the training frames) over ``bg``: the shared step's source frame."""
    from trioman.runtime.pseudo_gt import Source

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
    from trioman.runtime.generator import sample
    from trioman.runtime.metrics import psnr as psnr_db
    from trioman.runtime.pseudo_gt import PseudoConfig, make_pseudo_frames
    from trioman.toolkit.train.augmentation import render_candidate
    from trioman.toolkit.train.pseudo_models import load_pseudo_examiner, load_pseudo_refiner

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


def _bar_charts(report: dict, out: Path) -> None:
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
             + ("poses fitted by `trioman fit` from each subject's video (every frame; a phone's focal prior), the test "
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
              "toolkit/triplets.py):", "", "| input | tex+geo | warp+geo |", "|---|---|---|"]
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
