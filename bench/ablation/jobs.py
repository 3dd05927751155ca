"""Training the ablation's avatar runs: ``Job`` (one run, from scratch or forked from a warm-up), the cost model
that orders them, and the scheduler that trains them in worker processes."""

from __future__ import annotations

import concurrent.futures
import multiprocessing
import os
import time
from dataclasses import dataclass
from pathlib import Path

import torch

from trioman.toolkit.lpips import load_lpips
from trioman.toolkit.train.config import TrainConfig
from trioman.toolkit.train.fork import fork_run
from trioman.toolkit.train.loop import train


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
    if job.fork is not None and not (job.run / "config.json").exists():
        fork_run(job.fork[0], job.run, job.cfg, job.fork[1])
    train(job.subject, job.run, job.cfg, resume=(job.run / "config.json").exists(), progress=False, lpips=lpips,
          stop_after=job.stop_after)


def _train_run(job: Job, threads: int, with_lpips: bool) -> None:
    """One avatar run in a worker process of ``train_in_parallel``, with ``threads`` torch threads."""
    torch.set_num_threads(threads)
    run_job(job, load_lpips() if with_lpips else None)


def train_in_parallel(todo: list[Job], jobs: int, with_lpips: bool) -> None:
    """Train the runs ``todo`` in ``jobs`` worker processes, each with an equal share of the cores (at least one
    thread); a forked run starts once the warm-up it forks from is done (warm-ups are ``todo``'s jobs that
    stop early, started first), and of the runs ready to start the longest goes first (``_cost``); one line per
    finished run. A failed run stops the others not yet started and is raised naming its folder (the finished
    ones stay; a rerun resumes the rest)."""
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
