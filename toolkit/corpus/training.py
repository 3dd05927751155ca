"""Training the Refiner and Examiner on a synthetic corpus (``trioman synth-corpus``): triplet batches
as model tensors, and one function per model that trains it into a run folder (resumable).

Batches are drawn from the training subjects' triplets: a frame T, its coarse render and normal map,
and a GT frame T+k of the same sequence (0 < |k| <= k_max), as in the paper's data construction.
"""

from __future__ import annotations

import itertools
import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Sequence

import numpy as np
import torch

from trioman.runtime.outputs import FolderKind, atomic_write_text
from trioman.toolkit.corpus.build import triplet_paths
from trioman.toolkit.distributed import Ranks, barrier, current, torch_device
from trioman.toolkit.examiner import ExaminerBatch, ExaminerTrainConfig, create_examiner, examiner_loop, pair_auroc
from trioman.toolkit.refiner import RefinerBatch, RefinerConfig, RefinerTrainConfig, create_refiner, refiner_loop
from trioman.toolkit.loops.checkpoint import CHECKPOINTS, SELECTED, latest_checkpoint
from trioman.toolkit.corpus_training_options import TrainExaminerOptions, TrainRefinerOptions
from trioman.toolkit.corpus.triplets import TripletSet, Tuples


def nchw(x: np.ndarray) -> torch.Tensor:
    """[B, H, W, 3] float32 -> [B, 3, H, W] tensor."""
    return torch.from_numpy(np.ascontiguousarray(x.transpose(0, 3, 1, 2)))


def refiner_batch(t: Tuples) -> RefinerBatch:
    ref = nchw(t.reference)
    return RefinerBatch(coarse=nchw(t.coarse), reference=ref, normal=nchw(t.normal), target=nchw(t.gt), reference_target=ref,
                        aligned=None if t.aligned is None else nchw(t.aligned))


def examiner_batch(t: Tuples) -> ExaminerBatch:
    return ExaminerBatch(gt=nchw(t.gt), coarse=nchw(t.coarse), reference=nchw(t.reference))


# Refiner sizes: "compact" (narrower widths, for CPU training; docs/findings.md, "Refiner"), "default"
# is RefinerConfig's.
FIT_JSON = "fit.json"  # run/fit.json: what fit_refiner / fit_examiner trained, on what, how long
# a fit_refiner / fit_examiner run: what a command that starts fresh models in a fixed folder may remove
MODEL_RUN = FolderKind("Refiner or Examiner run", FIT_JSON, files=(FIT_JSON, SELECTED), folders=((CHECKPOINTS, ("ckpt_*.pt",)),))
REFINER_SIZES = {"compact": dict(vae_widths=(16, 32, 48), unet_widths=(32, 64, 64)), "default": {}}


@dataclass(frozen=True)
class FitConfig:
    steps: int = TrainRefinerOptions.steps
    batch: int = TrainRefinerOptions.batch
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


def refiner_fit(options: TrainRefinerOptions) -> FitConfig:
    """The FitConfig of `trioman train-refiner`'s options."""
    return FitConfig(steps=options.steps, batch=options.batch, crop=options.crop, seed=options.seed,
                     baseline_frames=options.baseline_frames)


def examiner_fit(options: TrainExaminerOptions) -> FitConfig:
    """The FitConfig of `trioman train-examiner`'s options: whole frames (no crop), the Examiner's learning rate."""
    return FitConfig(steps=options.steps, batch=options.batch, lr=options.lr, crop=None, seed=options.seed,
                     baseline_frames=options.baseline_frames)


def crop_windows(shape: tuple[int, int], n: int, side: int | None,
                 rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray] | None:
    """Top-left corners (ys [n], xs [n]) of random ``side`` x ``side`` windows of an H x W frame; None,
    drawing nothing, when ``side`` is None or not smaller than the frame."""
    H, W = shape
    if side is None or side >= min(H, W):
        return None
    return rng.integers(0, H - side + 1, n), rng.integers(0, W - side + 1, n)


def cut(t: Tuples, side: int | None, windows: tuple[np.ndarray, np.ndarray] | None) -> Tuples:
    """Sample b's images cut at window b (``crop_windows``); ``t`` itself for None."""
    if windows is None:
        return t
    return Tuples(*(None if a is None else np.stack([a[b, y:y + side, x:x + side] for b, (y, x) in enumerate(zip(*windows))])
                    for a in t))


def random_crop(t: Tuples, side: int | None, rng: np.random.Generator) -> Tuples:
    """The same random ``side`` x ``side`` window of every image of each sample (all of it if None or
    larger than the frame)."""
    return cut(t, side, crop_windows(t.gt.shape[1:3], len(t.gt), side, rng))


class SampleStream:
    """The batches of a run: step s's global batch of world size x ``fit.batch`` samples is the s-th
    draw (frames, then crop windows) of one generator seeded with ``fit.seed``, the same on every
    rank; each rank gathers and crops only its own rows (``Ranks.rows``). Asked for a later step, the
    stream draws the indices of the steps in between, so a resumed run sees an uninterrupted run's
    batches. One process draws exactly what ``data.sample`` then ``random_crop`` would."""

    def __init__(self, data: TripletSet, fit: FitConfig, ranks: Ranks | None = None) -> None:
        ranks = ranks or Ranks()
        self.data, self.fit, self.rows = data, fit, ranks.rows(fit.batch)
        self.size = fit.batch * ranks.world_size
        self.rng = np.random.default_rng(fit.seed)
        self.step = 0  # the step of the next draw

    def _draw(self) -> tuple[np.ndarray, np.ndarray, tuple[np.ndarray, np.ndarray] | None]:
        t, ref = self.data.draw(self.rng, self.size, self.fit.k_max, self.fit.split)
        windows = crop_windows(self.data.gt.shape[1:3], self.size, self.fit.crop, self.rng)
        self.step += 1
        return t, ref, windows

    def __call__(self, step: int) -> Tuples:
        """This rank's samples of step ``step`` (>= the last step asked for)."""
        if step < self.step:
            raise ValueError(f"step: the stream is at step {self.step}, cannot go back to {step}")
        while self.step < step:
            self._draw()
        t, ref, windows = self._draw()
        rows = self.rows
        return cut(self.data.take(t[rows], ref[rows]), self.fit.crop, None if windows is None else (windows[0][rows], windows[1][rows]))


def training_triplets(source: str | Path | Sequence[str | Path], variant: str = "all") -> list[Path]:
    """Triplet files to train on: a corpus folder's training subjects (of ``variant``), or the given
    list of triplet .npz files (e.g. one subject's, ``trioman triplets``)."""
    if isinstance(source, (str, Path)):
        return triplet_paths(source, variant)["train"]
    files = [Path(p) for p in source]
    if not files:
        raise ValueError("triplets: no triplet files given")
    return files


def _stream(source: str | Path | Sequence[str | Path], fit: FitConfig, ranks: Ranks) -> SampleStream:
    data = TripletSet.load(training_triplets(source, fit.baseline_frames))
    if fit.image_size is not None:
        data = data.resized(fit.image_size)
    return SampleStream(data, fit, ranks)


def _finish(run: Path, info: dict, previous: dict | None, ranks: Ranks) -> dict:
    """Write fit.json (rank 0 alone; every rank waits for it); a run that was already complete keeps
    the record (and wall time) of the call that trained it."""
    if previous is not None and _same_fit(previous.get("fit", {}), info["fit"]):
        return previous
    if ranks.main:
        run.mkdir(parents=True, exist_ok=True)
        atomic_write_text(run / FIT_JSON, json.dumps(info, indent=2) + "\n")
    barrier()
    return info


def _same_fit(old: dict, new: dict) -> bool:
    """Two fit records agree; fields added since ``old`` was written count at their defaults."""
    defaults = asdict(FitConfig())
    return all(old.get(k, defaults.get(k)) == v for k, v in new.items())


def _earlier_seconds(run: Path, fit: dict) -> float:
    """Wall time already spent on ``run`` by a call with the same fit but fewer steps (a run being
    resumed to more steps), so fit.json keeps the total; 0 for a new run."""
    path = run / FIT_JSON
    if not path.is_file():
        return 0.0
    old = json.loads(path.read_text())
    same = _same_fit({**old.get("fit", {}), "steps": fit["steps"]}, fit)
    return float(old.get("seconds", 0.0)) if same and old["fit"].get("steps", 0) < fit["steps"] else 0.0


def _resume_step(run: Path) -> int:
    """The step of the run's latest checkpoint (where training resumes), 0 without one."""
    ckpt = latest_checkpoint(run)
    return 0 if ckpt is None else int(ckpt.stem.split("_")[-1])


def _previous(run: Path, steps: int) -> dict | None:
    """fit.json of a complete run (its last checkpoint reached ``steps``), else None."""
    if not (run / FIT_JSON).is_file() or _resume_step(run) < steps:
        return None
    return json.loads((run / FIT_JSON).read_text())


def fit_refiner(corpus: str | Path | Sequence[str | Path], run: str | Path, conditions: str = TrainRefinerOptions.conditions,
                fit: FitConfig | None = None, refiner_size: str = TrainRefinerOptions.size, model_cfg: RefinerConfig | None = None,
                lpips=None, *, backbone: str = TrainRefinerOptions.backbone, pretrained: str | None = None,
                device: str = TrainRefinerOptions.device, mixed_precision: str = TrainRefinerOptions.mixed_precision,
                gradient_checkpointing: bool = TrainRefinerOptions.gradient_checkpointing) -> tuple[torch.nn.Module, dict]:
    """Train a Refiner with ``conditions`` on the corpus's training subjects (or a list of triplet
    files) into ``run`` on ``device`` ("cpu" or "cuda"). -> (model, info). ``backbone`` "sd-turbo"
    builds on the local diffusers folder ``pretrained`` (``refiner_size`` then does not apply);
    ``mixed_precision`` and ``gradient_checkpointing`` are RefinerTrainConfig's. Under torchrun
    (toolkit/distributed.py) ``fit.batch`` is per rank and the ranks share the run (docs/scaling.md). The defaults
    are `trioman train-refiner`'s (toolkit/corpus_training_options.py)."""
    run = Path(run)
    fit = refiner_fit(TrainRefinerOptions()) if fit is None else fit
    ranks = current()
    previous = _previous(run, fit.steps)
    stream = _stream(corpus, fit, ranks)
    size = fit.crop or stream.data.gt.shape[1]
    widths = REFINER_SIZES[refiner_size] if backbone == "scratch" else {}
    cfg = model_cfg or RefinerConfig(image_size=size, conditions=conditions, backbone=backbone, pretrained_path=pretrained, **widths)
    torch.manual_seed(fit.seed)
    model = create_refiner(cfg, seed=fit.seed).to(torch_device(device, ranks))
    t = time.perf_counter() - _earlier_seconds(run, asdict(fit))
    train_cfg = RefinerTrainConfig(steps=fit.steps, lr=fit.lr, mixed_precision=mixed_precision, gradient_checkpointing=gradient_checkpointing)
    result = refiner_loop(model, lambda step: refiner_batch(stream(step)), train_cfg, run=run, lpips=lpips, progress=True)
    info = {"model": "refiner", "conditions": conditions, "fit": asdict(fit), "config": cfg.to_dict(), "device": device,
            "distributed": ranks.record(fit.batch, fit.seed), "seconds": time.perf_counter() - t,
            "final_loss": float(np.mean(result.losses[-50:])) if result.losses else None,
            "skipped_steps": result.skipped, "checkpoint": str(result.checkpoint)}
    return model, _finish(run, info, previous, ranks)


def fit_examiner(corpus: str | Path | Sequence[str | Path], run: str | Path, name: str = TrainExaminerOptions.model,
                 fit: FitConfig | None = None, pairing: str = TrainExaminerOptions.pairing,
                 validation_subjects: int = TrainExaminerOptions.validation_subjects,
                 validate_every: int = TrainExaminerOptions.validate_every, *, device: str = TrainExaminerOptions.device,
                 mixed_precision: str = TrainExaminerOptions.mixed_precision) -> tuple[torch.nn.Module, dict]:
    """Train an Examiner (a registered config name) on the corpus's training subjects (or a list of
    triplet files) into ``run``, at the triplets' size or ``fit.image_size``, with ``pairing``
    (``sample_pairs``: "contrast" or the paper's random draw).

    The last ``validation_subjects`` training subjects (files) are held out of training: every
    ``validate_every`` steps the AUROC of real vs coarse pairs on all their frames (reference T+k,
    the paper's pairs) is measured and the model keeps the weights of the best step (run/selected.pt,
    what export and bench deploy load). 0 trains on every subject and keeps the last step.

    ``device`` "cpu" or "cuda"; ``mixed_precision`` is ExaminerTrainConfig's. Under torchrun
    (toolkit/distributed.py) ``fit.batch`` is per rank and the ranks share the run (docs/scaling.md). The defaults
    are `trioman train-examiner`'s (toolkit/corpus_training_options.py).
    """
    run = Path(run)
    fit = examiner_fit(TrainExaminerOptions()) if fit is None else fit
    ranks = current()
    dev = torch_device(device, ranks)
    files = training_triplets(corpus, fit.baseline_frames)
    if not isinstance(validation_subjects, int) or not 0 <= validation_subjects < len(files):
        raise ValueError(f"validation_subjects: must be an integer in [0, {len(files) - 1}] for {len(files)} training "
                         f"subjects, got {validation_subjects!r}")
    if not isinstance(validate_every, int) or validate_every < 1:
        raise ValueError(f"validate_every: must be a positive integer, got {validate_every!r}")
    record = {**asdict(fit), "pairing": pairing, "validation_subjects": validation_subjects, "validate_every": validate_every}
    previous = _previous(run, fit.steps)
    stream = _stream(files[:len(files) - validation_subjects], fit, ranks)
    validate = None
    if validation_subjects:
        held = TripletSet.load(files[-validation_subjects:])
        if fit.image_size is not None:
            held = held.resized(fit.image_size)
        val = ExaminerBatch(*(x.to(dev) for x in examiner_batch(held.nearby(None, fit.k_max, fit.seed))))
        validate = lambda model: pair_auroc(model, val.gt, val.coarse, val.reference)  # noqa: E731
    torch.manual_seed(fit.seed)
    model = create_examiner(name, img_size=stream.data.gt.shape[1]).to(dev)
    t = time.perf_counter() - _earlier_seconds(run, record)

    def batches():
        for step in itertools.count(_resume_step(run)):  # examiner_loop resumes from the same checkpoint
            yield examiner_batch(stream(step))

    every = validate_every if validation_subjects else ExaminerTrainConfig.checkpoint_every
    train_cfg = ExaminerTrainConfig(steps=fit.steps, lr=fit.lr, seed=fit.seed, pairing=pairing, checkpoint_every=every,
                                    mixed_precision=mixed_precision)
    result = examiner_loop(model, batches(), train_cfg, run=run, validate=validate, progress=True)
    info = {"model": "examiner", "name": name, "fit": record, "config": model.config.to_dict(), "device": device,
            "distributed": ranks.record(fit.batch, fit.seed), "seconds": time.perf_counter() - t,
            "final_loss": float(np.mean(result.losses[-50:])) if result.losses else None,
            "skipped_steps": result.skipped, "checkpoint": str(result.selected or result.checkpoint)}
    if validation_subjects:
        info.update(selected_step=result.selected_step, validation_auroc={str(k): v for k, v in result.validation.items()})
    return model, _finish(run, info, previous, ranks)
