"""The Refiners and the Examiner the ablation's rows use: trained on the corpus's training subjects in OUT/models,
or the ones already there."""

from __future__ import annotations

import json
from pathlib import Path

from trioman.bench.ablation_config import AblationBenchConfig
from trioman.toolkit.corpus.training import FitConfig, fit_examiner, fit_refiner


def _model_run(out: Path, key: str) -> Path:
    return out / "models" / key.replace("+", "_")


def train_models(corpus: Path, out: Path, config: AblationBenchConfig, keys: list[str]) -> tuple[dict[str, Path], dict]:
    """Train (or reuse, when finished) the models ``keys`` in OUT/models; the others already there are used too."""
    fit = FitConfig(steps=config.refiner_steps, batch=config.batch, crop=config.crop, baseline_frames=config.baseline_frames)
    for key in keys:
        if key == "examiner":
            fit_examiner(corpus, _model_run(out, key), config.examiner,
                         FitConfig(steps=config.examiner_steps, batch=config.batch, lr=3e-4, crop=None,
                                   baseline_frames=config.baseline_frames))
        else:
            fit_refiner(corpus, _model_run(out, key), key.removeprefix("refiner_"), fit, config.refiner_size)
    return trained_models(out)


def trained_models(out: Path) -> tuple[dict[str, Path], dict]:
    """The models trained in ``out/models`` (a report uses what is there), as train_models returns them."""
    paths, info = {}, {}
    for key in ("refiner_none", "refiner_tex", "refiner_tex+geo", "refiner_warp", "refiner_warp+geo", "examiner"):
        run = _model_run(out, key)
        if not (run / "fit.json").is_file():
            continue
        fit = json.loads((run / "fit.json").read_text())
        paths[key], info[key] = run, {"seconds": fit["seconds"], "steps": fit["fit"]["steps"]}
    return paths, info
