"""Training the Refiner and Examiner on a synthetic corpus (``trioman synth-corpus``): triplet batches
as model tensors, and one function per model that trains it into a run folder (resumable).

Batches are drawn from the training subjects' triplets: a frame T, its coarse render and normal map,
and a GT frame T+k of the same sequence (0 < |k| <= k_max), as in the paper's data construction.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Sequence

import numpy as np
import torch

from trioman.runtime.image_io import atomic_write_text
from trioman.toolkit.corpus import triplet_paths
from trioman.toolkit.examiner import ExaminerBatch, ExaminerTrainConfig, create_examiner, pair_auroc, train_examiner
from trioman.toolkit.refiner import RefinerBatch, RefinerConfig, RefinerTrainConfig, create_refiner, train_refiner
from trioman.toolkit.triplets import TripletSet, Tuples


def nchw(x: np.ndarray) -> torch.Tensor:
    """[B, H, W, 3] float32 -> [B, 3, H, W] tensor."""
    return torch.from_numpy(np.ascontiguousarray(x.transpose(0, 3, 1, 2)))


def refiner_batch(t: Tuples) -> RefinerBatch:
    ref = nchw(t.reference)
    return RefinerBatch(coarse=nchw(t.coarse), reference=ref, normal=nchw(t.normal), target=nchw(t.gt), reference_target=ref)


def examiner_batch(t: Tuples) -> ExaminerBatch:
    return ExaminerBatch(gt=nchw(t.gt), coarse=nchw(t.coarse), reference=nchw(t.reference))


# Refiner sizes: "compact" (narrower widths, for CPU training; docs/findings.md, "Refiner"), "default"
# is RefinerConfig's.
REFINER_SIZES = {"compact": dict(vae_widths=(16, 32, 48), unet_widths=(32, 64, 64)), "default": {}}


@dataclass(frozen=True)
class FitConfig:
    steps: int = 1500
    batch: int = 4
    k_max: int = 4  # |k| of the texture/reference frame T+k
    lr: float = 2e-4
    seed: int = 0
    baseline_frames: str = "all"  # which training-subject triplets: "all" or "subset" (corpus variants)
    crop: int | None = 64  # train on random square crops of this side (same place in every image of a
    # sample); the models are convolutional with position-free attention and run on full frames after
    image_size: int | None = None  # resize the triplets to this side first (the Examiner's input size)
    split: str | None = None  # draw frames T of this split only ("train"; None: every frame, as for corpus subjects)

    def __post_init__(self) -> None:
        for name in ("steps", "batch", "k_max"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name}: must be >= 1, got {getattr(self, name)}")
        if self.crop is not None and (self.crop < 16 or self.crop % 16):
            raise ValueError(f"crop: must be a multiple of 16 (>= 16) or None, got {self.crop}")
        if self.image_size is not None and (self.image_size < 16 or self.image_size % 16):
            raise ValueError(f"image_size: must be a multiple of 16 (>= 16) or None, got {self.image_size}")


def random_crop(t: Tuples, side: int | None, rng: np.random.Generator) -> Tuples:
    """The same random ``side`` x ``side`` window of every image of each sample (all of it if None or
    larger than the frame)."""
    H, W = t.gt.shape[1:3]
    if side is None or side >= min(H, W):
        return t
    ys = rng.integers(0, H - side + 1, len(t.gt))
    xs = rng.integers(0, W - side + 1, len(t.gt))
    return Tuples(*(np.stack([a[b, y:y + side, x:x + side] for b, (y, x) in enumerate(zip(ys, xs))]) for a in t))


def training_triplets(source: str | Path | Sequence[str | Path], variant: str = "all") -> list[Path]:
    """Triplet files to train on: a corpus folder's training subjects (of ``variant``), or the given
    list of triplet .npz files (e.g. one subject's, ``trioman triplets``)."""
    if isinstance(source, (str, Path)):
        return triplet_paths(source, variant)["train"]
    files = [Path(p) for p in source]
    if not files:
        raise ValueError("triplets: no triplet files given")
    return files


def _sampler(source: str | Path | Sequence[str | Path], fit: FitConfig):
    data = TripletSet.load(training_triplets(source, fit.baseline_frames))
    if fit.image_size is not None:
        data = data.resized(fit.image_size)
    rng = np.random.default_rng(fit.seed)
    return data, (lambda: random_crop(data.sample(rng, fit.batch, fit.k_max, fit.split), fit.crop, rng))


def _finish(run: Path, info: dict, previous: dict | None) -> dict:
    """Write fit.json; a run that was already complete keeps the record (and wall time) of the call
    that trained it."""
    if previous is not None and _same_fit(previous.get("fit", {}), info["fit"]):
        return previous
    run.mkdir(parents=True, exist_ok=True)
    atomic_write_text(run / "fit.json", json.dumps(info, indent=2) + "\n")
    return info


def _same_fit(old: dict, new: dict) -> bool:
    """Two fit records agree; fields added since ``old`` was written count at their defaults."""
    defaults = asdict(FitConfig())
    return all(old.get(k, defaults.get(k)) == v for k, v in new.items())


def _earlier_seconds(run: Path, fit: dict) -> float:
    """Wall time already spent on ``run`` by a call with the same fit but fewer steps (a run being
    resumed to more steps), so fit.json keeps the total; 0 for a new run."""
    path = run / "fit.json"
    if not path.is_file():
        return 0.0
    old = json.loads(path.read_text())
    same = _same_fit({**old.get("fit", {}), "steps": fit["steps"]}, fit)
    return float(old.get("seconds", 0.0)) if same and old["fit"].get("steps", 0) < fit["steps"] else 0.0


def _previous(run: Path, steps: int) -> dict | None:
    """fit.json of a complete run (its last checkpoint reached ``steps``), else None."""
    from trioman.toolkit.train.checkpoint import latest_checkpoint

    ckpt = latest_checkpoint(run)
    if ckpt is None or not (run / "fit.json").is_file() or int(ckpt.stem.split("_")[-1]) < steps:
        return None
    return json.loads((run / "fit.json").read_text())


def fit_refiner(corpus: str | Path | Sequence[str | Path], run: str | Path, conditions: str = "tex+geo", fit: FitConfig = FitConfig(),
                refiner_size: str = "compact", model_cfg: RefinerConfig | None = None, lpips=None, *, backbone: str = "scratch",
                pretrained: str | None = None, device: str = "cpu", mixed_precision: str = "no",
                gradient_checkpointing: bool = False) -> tuple[torch.nn.Module, dict]:
    """Train a Refiner with ``conditions`` on the corpus's training subjects (or a list of triplet
    files) into ``run`` on ``device``. -> (model, info). ``backbone`` "sd-turbo" builds on the local
    diffusers folder ``pretrained`` (``refiner_size`` then does not apply); ``mixed_precision`` and
    ``gradient_checkpointing`` are RefinerTrainConfig's."""
    run = Path(run)
    previous = _previous(run, fit.steps)
    data, draw = _sampler(corpus, fit)
    size = fit.crop or data.gt.shape[1]
    widths = REFINER_SIZES[refiner_size] if backbone == "scratch" else {}
    cfg = model_cfg or RefinerConfig(image_size=size, conditions=conditions, backbone=backbone, pretrained_path=pretrained, **widths)
    torch.manual_seed(fit.seed)
    model = create_refiner(cfg, seed=fit.seed).to(device)
    t = time.perf_counter() - _earlier_seconds(run, asdict(fit))
    train_cfg = RefinerTrainConfig(steps=fit.steps, lr=fit.lr, mixed_precision=mixed_precision, gradient_checkpointing=gradient_checkpointing)
    result = train_refiner(model, lambda step: refiner_batch(draw()), train_cfg, run=run, lpips=lpips, progress=True)
    info = {"model": "refiner", "conditions": conditions, "fit": asdict(fit), "config": cfg.to_dict(), "device": device,
            "seconds": time.perf_counter() - t, "final_loss": float(np.mean(result.losses[-50:])) if result.losses else None,
            "skipped_steps": result.skipped, "checkpoint": str(result.checkpoint)}
    return model, _finish(run, info, previous)


def fit_examiner(corpus: str | Path | Sequence[str | Path], run: str | Path, name: str = "examiner_nano", fit: FitConfig = FitConfig(lr=3e-4),
                 pairing: str = "contrast", validation_subjects: int = 1, validate_every: int = 100) -> tuple[torch.nn.Module, dict]:
    """Train an Examiner (a registered config name) on the corpus's training subjects (or a list of
    triplet files) into ``run``, at the triplets' size or ``fit.image_size``, with ``pairing``
    (``sample_pairs``: "contrast" or the paper's random draw).

    The last ``validation_subjects`` training subjects (files) are held out of training: every
    ``validate_every`` steps the AUROC of real vs coarse pairs on all their frames (reference T+k,
    the paper's pairs) is measured and the model keeps the weights of the best step (run/selected.pt,
    what export and bench deploy load). 0 trains on every subject and keeps the last step.
    """
    run = Path(run)
    files = training_triplets(corpus, fit.baseline_frames)
    if not isinstance(validation_subjects, int) or not 0 <= validation_subjects < len(files):
        raise ValueError(f"validation_subjects: must be an integer in [0, {len(files) - 1}] for {len(files)} training "
                         f"subjects, got {validation_subjects!r}")
    if not isinstance(validate_every, int) or validate_every < 1:
        raise ValueError(f"validate_every: must be a positive integer, got {validate_every!r}")
    record = {**asdict(fit), "pairing": pairing, "validation_subjects": validation_subjects, "validate_every": validate_every}
    previous = _previous(run, fit.steps)
    data, draw = _sampler(files[:len(files) - validation_subjects], fit)
    validate = None
    if validation_subjects:
        held = TripletSet.load(files[-validation_subjects:])
        if fit.image_size is not None:
            held = held.resized(fit.image_size)
        val = examiner_batch(held.nearby(None, fit.k_max, fit.seed))
        validate = lambda model: pair_auroc(model, val.gt, val.coarse, val.reference)  # noqa: E731
    torch.manual_seed(fit.seed)
    model = create_examiner(name, img_size=data.gt.shape[1])
    t = time.perf_counter() - _earlier_seconds(run, record)

    def batches():
        while True:
            yield examiner_batch(draw())

    every = validate_every if validation_subjects else ExaminerTrainConfig.checkpoint_every
    result = train_examiner(model, batches(), ExaminerTrainConfig(steps=fit.steps, lr=fit.lr, seed=fit.seed, pairing=pairing,
                                                                  checkpoint_every=every), run=run, validate=validate,
                            progress=True)
    info = {"model": "examiner", "name": name, "fit": record, "config": model.config.to_dict(),
            "seconds": time.perf_counter() - t, "final_loss": float(np.mean(result.losses[-50:])) if result.losses else None,
            "skipped_steps": result.skipped, "checkpoint": str(result.selected or result.checkpoint)}
    if validation_subjects:
        info.update(selected_step=result.selected_step, validation_auroc={str(k): v for k, v in result.validation.items()})
    return model, _finish(run, info, previous)
