"""What the ablation trains: each variant's training config (its augmentation settings beyond its mode and
Refiner condition), its runs and their length, the models the rows need, and the jobs still to train (warm-ups
first)."""

from __future__ import annotations

import dataclasses
import functools
from pathlib import Path

from trioman.bench.ablation.jobs import Job
from trioman.bench.ablation_config import ALL_VARIANTS, LEVERS, AblationPlan
from trioman.toolkit.corpus.build import finished
from trioman.toolkit.train.config import preset

# AugmentConfig settings of a variant beyond its mode and Refiner condition.
SETTINGS = {"GRk_warp+geo": {"keep_carried": True}, "GRE": {"keep_carried": True}}


def variant_runs(plan: AblationPlan) -> list[tuple[str, int]]:
    return [(name, seed) for name, _, _, seeded in plan.variants for seed in (range(plan.seeds) if seeded else (0,))]


def _train_config(name: str, seed: int, plan: AblationPlan, models: dict[str, Path]):
    mode, cond = next((m, c) for n, m, c, _ in ALL_VARIANTS if n == name)
    avatar = dataclasses.replace(preset("quick").avatar, seed=seed)  # a seed draws the initial weights too
    # every row, the control's included, trains without pose corrections (their default is on for trioman fit's
    # subjects without --augment): the ablation measures the augmentation alone
    quick = functools.partial(preset, "quick", seed=seed, avatar=avatar, refine_poses=False)
    if name == "baseline":
        return quick(iterations=plan.iterations)
    iterations = plan.augmented_iterations
    if mode is None:
        return quick(iterations=iterations)
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
    return quick(iterations=iterations, augment=aug, checkpoint_every=iterations)


def needed_models(variants: list[str]) -> list[str]:
    """The models (keys "refiner_<condition>", "examiner") that training ``variants`` needs (the condition check
    covers the tex+geo and warp+geo Refiners that are there: with every row, both)."""
    conds = {c for n, _, c, _ in ALL_VARIANTS if n in variants and c is not None}
    keys = [f"refiner_{c}" for c in ("none", "tex", "tex+geo", "warp", "warp+geo") if c in conds]
    return keys + (["examiner"] if "GRE" in variants else [])


def run_iterations(name: str, plan: AblationPlan) -> int:
    return plan.iterations if name == "baseline" else plan.augmented_iterations


def plan_jobs(plan: AblationPlan, out: Path, subjects: dict[str, Path], models: dict[str, Path], only: set[str] | None,
              threads: int) -> list[Job]:
    """The runs of ``subjects`` {held-out name: regime subject folder} still to train (``only`` those variants),
    warm-ups first: the runs of one subject and seed as long as an augmented run, two or more of them not yet
    started, fork from one shared real-frame warm-up (the control's first ``start`` steps, trained once with
    ``threads`` torch threads, the count the forks train with; toolkit/train/fork.py)."""
    step = int(round(plan.schedule.start * plan.augmented_iterations))
    warmups, jobs = [], []
    for h, subject in subjects.items():
        runs = [(v, seed, plan.run(out, h, v, seed)) for v, seed in variant_runs(plan) if only is None or v in only]
        runs = [(v, seed, r) for v, seed, r in runs if not finished(r, run_iterations(v, plan))]
        for seed in sorted({seed for _, seed, _ in runs}):
            fresh = [r for v, s, r in runs if s == seed and run_iterations(v, plan) == plan.augmented_iterations
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
