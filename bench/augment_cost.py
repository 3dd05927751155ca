"""``trioman bench augment-cost``: the wall time of the default augmented run (``trioman train --augment``, the
schedule and kind a user gets with no other option) against the plain run at equal steps, at each size.

    trioman bench augment-cost --out DIR [--size N] [--frames 96] [--iterations 300]

Per size (default 128 and 256 px; ``--size`` one of them): a synthetic subject seen over a third of a turn (the
regime the augmentation's gain was measured in), then the quick preset trained plain and with the default
augmentation, one after the other in this process (the same threads), each timed from its first step to its
last checkpoint; the augmented run's stage seconds come from its RUN/augment.json. Issue 44's target: the
augmented run at most 1.3x the plain one's wall time.
"""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path

from trioman.bench.config import AugmentCostBenchConfig

TARGET_RATIO = 1.3
SIZES = (128, 256)


def bench_augment_cost(config: AugmentCostBenchConfig) -> dict:
    """The report of ``trioman bench augment-cost``."""
    import shutil

    from trioman.bench.common import machine
    from trioman.runtime.stages import lifetime_peak_rss_bytes, mib
    from trioman.toolkit.synth.subject import SynthConfig, synthesize_subject
    from trioman.toolkit.train.augment_config import ALONE, AugmentConfig
    from trioman.toolkit.train.config import preset
    from trioman.toolkit.train.loop import AUGMENT_JSON, train

    out = Path(config.out) / "augment_cost"
    rows = []
    for size in SIZES if config.size is None else (config.size,):
        subject = out / f"subject_{size}"
        if not (subject / "subject.json").is_file():
            synthesize_subject(SynthConfig(seed=config.seed, size=size, frames=config.frames, coverage=0.33), subject,
                               overwrite=subject.exists(), progress=False)
        augment = AugmentConfig(mode=ALONE)  # what `--augment` alone runs
        seconds = {}
        for name, aug in (("plain", None), ("augmented", augment)):
            run = out / f"run_{size}_{name}"
            shutil.rmtree(run, ignore_errors=True)  # this benchmark's own run folder: a fresh run every time
            cfg = preset("quick", iterations=config.iterations, checkpoint_every=config.iterations, augment=aug)
            t = time.perf_counter()
            train(subject, run, cfg, progress=False)
            seconds[name] = time.perf_counter() - t
        stats = json.loads((out / f"run_{size}_augmented" / AUGMENT_JSON).read_text())
        ratio = round(seconds["augmented"] / seconds["plain"], 3)
        rows.append({"size": size, "plain_s": round(seconds["plain"], 2), "augmented_s": round(seconds["augmented"], 2),
                     "ratio": ratio, "target_met": ratio <= TARGET_RATIO,
                     "augment_seconds": {k: round(v, 1) for k, v in stats["seconds"].items()},
                     "pseudo_steps": stats["pseudo_steps"], "entries": stats["entries"]})
        print(f"bench augment-cost: {size} px: plain {seconds['plain']:.1f} s, augmented {seconds['augmented']:.1f} s "
              f"({ratio:.2f}x)", flush=True)
    return {"target": "augment-cost", "machine": machine(), "frames": config.frames, "iterations": config.iterations,
            "augment": {k: v for k, v in dataclasses.asdict(augment).items() if k not in ("pose_sigma", "camera")},
            "rows": rows, "target_ratio": TARGET_RATIO, "peak_rss_mib": round(mib(lifetime_peak_rss_bytes()), 1)}


def augment_cost_markdown(r: dict) -> str:
    a = r["augment"]
    lines = [f"# trioman bench augment-cost ({r['frames']} frames, a third of a turn; {r['iterations']} steps a run)", "",
             f"Machine: {r['machine']}. The default augmented run: `--augment` alone = {a['mode']}, warm-up "
             f"{a['start']:g}, pool {a['pool']} rebuilt every {a['refresh']} steps, share {a['share']:g}. "
             f"Peak RSS {r['peak_rss_mib']} MiB.", "",
             f"| size | plain (s) | augmented (s) | ratio | <= {r['target_ratio']}x | pseudo steps | pool entries | "
             "augmentation's seconds by stage |", "|---|---|---|---|---|---|---|---|"]
    for row in r["rows"]:
        stages = ", ".join(f"{k} {v}" for k, v in row["augment_seconds"].items() if v)
        lines.append(f"| {row['size']} | {row['plain_s']} | {row['augmented_s']} | {row['ratio']:.2f} | "
                     f"{'yes' if row['target_met'] else 'no'} | {row['pseudo_steps']} | {row['entries']} | {stages} |")
    return "\n".join(lines + [""])
