"""``trioman bench scale``: data-parallel training throughput (docs/scaling.md). The Refiner's training
step (compact widths, tex+geo, random triplets: the step's cost does not depend on the pixels) runs in
1 and 2 processes on this machine (gloo, one torch thread each); the report gives samples per second,
the rank count, the measured communication share of a step and a prediction for 8 GPUs with what it
assumes.

Communication is measured two ways at 2 processes: the all-reduce of a tensor the size of the
gradients alone, against the step; and the step with its gradient all-reduce against the same step
under DDP's ``no_sync`` (what the overlap with backward leaves exposed)."""

from __future__ import annotations

import json
import os
import socket
import tempfile
import time
from pathlib import Path

from trioman.bench.common import machine
from trioman.bench.config import ScaleBenchConfig

WORLDS = (1, 2)
PREDICT_GPUS = 8
WARMUP = 2  # untimed steps before every timed series


def _ring_volume(n: int) -> float:
    """Bytes each rank sends in a ring all-reduce, per gradient byte: 2 (n - 1) / n."""
    return 2.0 * (n - 1) / n


def _measure(size: int, batch: int, steps: int, seed: int) -> dict:
    """Time ``steps`` training steps in this process's group (none for one process) -> seconds per
    step, and at 2+ processes the no_sync step and the bare gradient all-reduce."""
    import numpy as np
    import torch
    import torch.distributed as dist

    from trioman.toolkit.distributed import current, data_parallel
    from trioman.toolkit.corpus.training import REFINER_SIZES, FitConfig, SampleStream, refiner_batch
    from trioman.toolkit.refiner import RefinerConfig, create_refiner
    from trioman.toolkit.refiner.loop import train_step
    from trioman.toolkit.corpus.triplets import TripletSet

    ranks = current()
    rng = np.random.default_rng(seed)
    n = 16
    img = lambda: rng.integers(0, 256, (n, size, size, 3), dtype=np.uint8)  # noqa: E731
    data = TripletSet(img(), rng.integers(0, 256, (n, size, size), dtype=np.uint8), img(), img(), np.array(["train"] * n),
                      np.array(["0/a"] * n), np.zeros(n, np.int32), np.zeros(n, np.float32))
    stream = SampleStream(data, FitConfig(batch=batch, crop=None, seed=seed), ranks)
    model = create_refiner(RefinerConfig(image_size=size, conditions="tex+geo", **REFINER_SIZES["compact"]), seed=seed)
    optimizer = torch.optim.Adam(model.parameters(), lr=2e-4)
    net = data_parallel(model)
    step = 0

    def series(count: int) -> float:
        nonlocal step
        for _ in range(WARMUP):
            train_step(model, optimizer, refiner_batch(stream(step)), net=net)
            step += 1
        if ranks.world_size > 1:
            dist.barrier()
        t = time.perf_counter()
        for _ in range(count):
            train_step(model, optimizer, refiner_batch(stream(step)), net=net)
            step += 1
        return (time.perf_counter() - t) / count

    out = {"step_s": series(steps), "parameters": sum(p.numel() for p in model.parameters())}
    if ranks.world_size > 1:
        with net.no_sync():
            out["no_sync_step_s"] = series(steps)
        flat = torch.zeros(out["parameters"])
        dist.barrier()
        t = time.perf_counter()
        for _ in range(steps):
            dist.all_reduce(flat)
        out["allreduce_s"] = (time.perf_counter() - t) / steps
    return out


def _worker(rank: int, world: int, port: int, size: int, batch: int, steps: int, seed: int, result: str) -> None:
    import torch

    from trioman.toolkit.distributed import process_group

    os.environ.update(MASTER_ADDR="127.0.0.1", MASTER_PORT=str(port), WORLD_SIZE=str(world), RANK=str(rank),
                      LOCAL_RANK=str(rank))
    torch.set_num_threads(1)
    with process_group("cpu") as ranks:
        out = _measure(size, batch, steps, seed)
    if ranks.main:
        Path(result).write_text(json.dumps(out))


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def bench_scale(config: ScaleBenchConfig) -> dict:
    import torch

    size, batch, steps = config.size, config.batch, config.iterations
    runs = {}
    with tempfile.TemporaryDirectory() as tmp:
        for world in WORLDS:
            result = Path(tmp) / f"{world}.json"
            torch.multiprocessing.spawn(_worker, args=(world, _free_port(), size, batch, steps, config.seed, str(result)),
                                        nprocs=world)
            runs[world] = json.loads(result.read_text())
    rows = [{"processes": w, "global_batch": w * batch, "step_s": r["step_s"], "samples_per_s": w * batch / r["step_s"]}
            for w, r in runs.items()]
    one, two = runs[1], runs[2]
    exposed = max(0.0, two["step_s"] - two["no_sync_step_s"])
    comm = {"gradient_mib": 4 * two["parameters"] / 2**20, "allreduce_s": two["allreduce_s"],
            "allreduce_share": two["allreduce_s"] / two["step_s"], "no_sync_step_s": two["no_sync_step_s"],
            "exposed_s": exposed, "exposed_share": exposed / two["step_s"],
            "shared_cores_slowdown": two["no_sync_step_s"] / one["step_s"]}
    scale = _ring_volume(PREDICT_GPUS) / _ring_volume(2)
    bounds = {}
    for name, t_comm in (("allreduce", two["allreduce_s"]), ("exposed", exposed)):
        t8 = one["step_s"] + t_comm * scale
        bounds[name] = {"step_s": t8, "samples_per_s": PREDICT_GPUS * batch / t8,
                        "efficiency": one["step_s"] / t8}
    prediction = {
        "gpus": PREDICT_GPUS, **bounds,
        "assumes": [
            f"the per-rank batch stays {batch} (global batch {PREDICT_GPUS * batch}) and each GPU computes its share in the "
            "time one process takes here alone (a GPU shares no cores with the other ranks): the figure carries the ratio "
            "of compute to communication measured here over, not a GPU speed",
            f"the all-reduce is a bandwidth-bound ring: each rank sends 2 (n - 1) / n of the gradients, {scale:.2f}x the "
            f"2-process volume at {PREDICT_GPUS}, over links as fast relative to compute as this machine's shared memory "
            "(NVLink within one node; across nodes the network is slower)",
            "the communication time is between the bare gradient all-reduce (nothing exposed beyond it) and the exposed "
            "time measured here against no_sync (which also holds the all-reduce's competition for the shared cores)",
            "the data stream keeps up (each rank gathers only its rows) and nothing else is shared",
        ],
    }
    return {"machine": machine(), "threads_per_process": 1, "backend": "gloo", "model": "refiner compact tex+geo",
            "size": size, "batch_per_rank": batch, "timed_steps": steps, "runs": rows, "communication": comm,
            "prediction": prediction}


def scale_markdown(r: dict) -> str:
    c, p = r["communication"], r["prediction"]
    lines = [
        "# Data-parallel scaling (trioman bench scale)",
        "",
        f"{r['model']} Refiner, {r['size']} px, {r['batch_per_rank']} samples per rank and step, {r['timed_steps']} timed "
        f"steps; {r['backend']}, {r['threads_per_process']} torch thread per process; {r['machine']}.",
        "",
        "| processes | global batch | s / step | samples / s | speed-up |",
        "|---:|---:|---:|---:|---:|",
    ]
    base = r["runs"][0]["samples_per_s"]
    for row in r["runs"]:
        lines.append(f"| {row['processes']} | {row['global_batch']} | {row['step_s']:.3f} | {row['samples_per_s']:.2f} | "
                     f"{row['samples_per_s'] / base:.2f}x |")
    lines += [
        "",
        f"Communication at 2 processes: the all-reduce of the {c['gradient_mib']:.1f} MiB of gradients alone takes "
        f"{1000 * c['allreduce_s']:.1f} ms, {100 * c['allreduce_share']:.1f} % of a step; the step without its gradient "
        f"all-reduce (DDP no_sync) is {1000 * c['exposed_s']:.0f} ms, {100 * c['exposed_share']:.1f} %, shorter (what the "
        "overlap with backward leaves exposed). On this machine's shared cores a 2-process step without the all-reduce "
        f"takes {c['shared_cores_slowdown']:.2f}x the 1-process step.",
        "",
        f"Prediction for {p['gpus']} GPUs: {p['allreduce']['samples_per_s']:.1f} samples / s "
        f"({100 * p['allreduce']['efficiency']:.0f} % of {p['gpus']} x one process) with the bare all-reduce as the "
        f"communication, {p['exposed']['samples_per_s']:.1f} samples / s ({100 * p['exposed']['efficiency']:.0f} %) with "
        "the exposed time. It assumes:",
        "",
        *[f"- {a}" for a in p["assumes"]],
        "",
    ]
    return "\n".join(lines)
