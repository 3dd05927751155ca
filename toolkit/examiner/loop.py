"""The Examiner's training loop over batches, from scratch: Adam on the BCE of seeded sampled pairs, with optional
model selection on validation data (the weights of the best validated step are kept), in a ``ModelRun``
(toolkit/loops/model_run.py: resume, the non-finite guard, progress, atomic checkpoints)."""

from __future__ import annotations

import dataclasses
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator, NamedTuple

import torch
from torch import nn

from trioman.toolkit.distributed import MIXED_PRECISION, data_parallel
from trioman.toolkit.examiner.loss import examiner_loss
from trioman.toolkit.examiner.model import Examiner, ExaminerConfig, PatchLogits
from trioman.toolkit.examiner.pairs import PAIRINGS, ExaminerBatch, sample_pairs
from trioman.toolkit.loops.checkpoint import SELECTED, load_checkpoint, save_atomic
from trioman.toolkit.loops.settings import check_loop_settings
from trioman.toolkit.loops.model_run import ModelRun


@dataclass(frozen=True)
class ExaminerTrainConfig:
    steps: int = 2000
    lr: float = 3e-4
    weight_decay: float = 0.0
    checkpoint_every: int = 250
    keep_checkpoints: int = 2
    seed: int = 0
    pairing: str = "contrast"  # sample_pairs: "contrast" (default) or "paper"
    max_skipped: int = 10  # consecutive steps with a non-finite loss or gradient that stop the run
    mixed_precision: str = "no"  # "bf16": the forward under torch.autocast, the loss in float32 (no loss scaling)

    def __post_init__(self) -> None:
        if self.mixed_precision not in MIXED_PRECISION:
            raise ValueError(f"mixed_precision: expected one of {MIXED_PRECISION}, got {self.mixed_precision!r}")
        if self.pairing not in PAIRINGS:
            raise ValueError(f"pairing: expected one of {PAIRINGS}, got {self.pairing!r}")
        if self.steps < 1:
            raise ValueError(f"steps: must be >= 1, got {self.steps}")
        if not self.lr > 0:
            raise ValueError(f"lr: must be > 0, got {self.lr}")
        if self.weight_decay < 0:
            raise ValueError(f"weight_decay: must be >= 0, got {self.weight_decay}")
        check_loop_settings(self)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


class ExaminerTrainResult(NamedTuple):
    losses: list[float]  # one per step of this call that updated the model (skipped ones excluded)
    step: int  # the step reached (resumed runs count from their checkpoint)
    checkpoint: Path | None  # the last checkpoint written, if a run folder was given
    selected_step: int | None = None  # with ``validate``: the step whose weights the model now holds
    validation: dict[int, float] | None = None  # with ``validate``: {step: value} of every validation
    selected: Path | None = None  # with ``validate`` and a run folder: run/selected.pt
    skipped: int = 0  # steps skipped for a non-finite loss or gradient, over the whole run


class _PairLogits(nn.Module):
    """The training forward, ``branch_logits(candidate, reference)[0]`` (upper-branch patch logits),
    as a module's ``forward``, so DistributedDataParallel can wrap it."""

    def __init__(self, examiner: Examiner) -> None:
        super().__init__()
        self.examiner = examiner

    def forward(self, candidate: torch.Tensor, reference: torch.Tensor) -> PatchLogits:
        return self.examiner.branch_logits(candidate, reference)[0]


def _batches(data: Iterable[ExaminerBatch]) -> Iterator[ExaminerBatch]:
    """Cycle a re-iterable source (a list, a DataLoader) forever."""
    while True:
        empty = True
        for batch in data:
            empty = False
            yield batch
        if empty:
            raise ValueError("data: yielded no batch")


def examiner_loop(
    model: Examiner,
    data: Iterable[ExaminerBatch],
    config: ExaminerTrainConfig = ExaminerTrainConfig(),
    run: str | os.PathLike | None = None,
    validate: Callable[[Examiner], float] | None = None,
    progress: bool = False,
) -> ExaminerTrainResult:
    """Train ``model`` in place for ``config.steps`` steps on pairs drawn by ``sample_pairs``;
    ``progress`` shows a bar with the loss and the last validation (on a terminal only).

    With ``run``, a checkpoint {step, model, config, train, optimizer, rng} is written atomically to
    run/checkpoints every ``checkpoint_every`` steps and at the end, and a run that finds one
    resumes from it (model, optimizer and pair-sampling RNG; ``data`` restarts from its beginning).

    ``validate(model) -> value`` (higher is better, e.g. AUROC on held-out subjects; called in eval
    mode without gradients) runs at the same steps; the model ends with the weights of the first
    step of the highest value, which are also written to run/selected.pt (checkpoint format, so
    ``load_examiner`` and the ONNX export read it) when training ends. The record (values and the
    selected weights) travels in every checkpoint, so a resumed run selects as an uninterrupted one.

    A step with a non-finite loss or gradient is skipped and counted (``ExaminerTrainResult.skipped``,
    kept in the checkpoints); ``config.max_skipped`` consecutive ones raise ``NonFiniteError``; a
    checkpoint is never written from non-finite weights.

    The model trains on its device (batches are moved there); ``config.mixed_precision`` "bf16" runs
    the forward under torch.autocast. Under torchrun (toolkit/distributed.py) ``data``
    yields this rank's share of each step, the pair draws are the global batch's (the same generator
    on every rank, this rank's rows taken), DDP averages the gradients, rank 0 alone writes files and
    shows progress, and a checkpoint resumes only at the world size that wrote it.
    """
    rng = torch.Generator().manual_seed(config.seed)  # the only randomness of the loop: pair sampling
    optimizer = torch.optim.Adam(model.parameters(), lr=config.lr, weight_decay=config.weight_decay)
    loop = ModelRun("examiner", "Examiner", model, optimizer, config, run, progress)
    history: dict[int, float] = {}
    best: tuple[int, dict[str, torch.Tensor]] | None = None  # (step, weights) of the best validation
    if loop.resumed:
        rng.set_state(loop.resumed["rng"])
        if validate is not None and "selection" in loop.resumed:
            sel = loop.resumed["selection"]
            history = {int(k): float(v) for k, v in sel["validation"].items()}
            best = (int(sel["step"]), sel["model"])
    hint = f"Lower the learning rate (lr={config.lr:g}) or check the data."
    model.train()
    net = data_parallel(_PairLogits(model))
    device = next(model.parameters()).device
    batches = _batches(data)
    while loop.running:
        batch = ExaminerBatch(*(x.to(device) for x in next(batches)))
        pairs = sample_pairs(batch, rng, config.pairing, (loop.ranks.rank, loop.ranks.world_size))
        with torch.autocast(device.type, dtype=torch.bfloat16, enabled=config.mixed_precision == "bf16"):
            upper = net(pairs.candidate, pairs.reference)
        loss = examiner_loss(PatchLogits(upper.scores.float(), upper.weights.float()), pairs.target)
        optimizer.zero_grad(set_to_none=True)
        value = None
        if loop.guard.finite_ok(loss, loop.step, "loss", hint):
            loss.backward()
            if loop.guard.grads_ok(model.parameters(), loop.step, hint):
                optimizer.step()
                value = loss.item()
            else:
                optimizer.zero_grad(set_to_none=True)
        boundary = loop.advance(value, **({"val": f"{history[max(history)]:.3f}"} if history else {}))
        if boundary and (validate is not None or run is not None):  # before a validation or a save
            loop.check_weights()
        if validate is not None and boundary:
            history[loop.step] = _validate(model, validate)
            if best is None or history[loop.step] > history[best[0]]:
                best = (loop.step, {k: v.detach().clone() for k, v in model.state_dict().items()})
        if run is not None and boundary:
            selection = {} if best is None else {
                "selection": {"validation": {str(k): v for k, v in history.items()}, "step": best[0], "model": best[1]}}
            loop.save({**loop.state(rng=rng.get_state()), **selection})
    selected = None
    if best is not None:
        model.load_state_dict(best[1])
        if run is not None and loop.ranks.main:
            selected = _save_selected(Path(run), best[0], best[1], model, config, history[best[0]])
    loop.finish()
    return ExaminerTrainResult(loop.losses, loop.step, loop.saved, best[0] if best else None,
                               None if validate is None else history, selected, loop.guard.skipped)


def _validate(model: Examiner, validate: Callable[[Examiner], float]) -> float:
    model.eval()
    with torch.no_grad():
        value = float(validate(model))
    model.train()
    if math.isnan(value):
        raise ValueError("validate: returned NaN")
    return value


def _save_selected(run: Path, step: int, weights: dict, model: Examiner, config: ExaminerTrainConfig, value: float) -> Path:
    """run/selected.pt: the selected weights in checkpoint format (no optimizer), written atomically."""
    path = run / SELECTED
    path.parent.mkdir(parents=True, exist_ok=True)
    save_atomic(path, {"step": step, "model": weights, "config": model.config.to_dict(), "train": config.to_dict(),
                       "validation": value})
    return path


def load_examiner(path: str | os.PathLike, exportable: bool = False) -> Examiner:
    """An Examiner rebuilt from a checkpoint written by ``examiner_loop`` (eval mode)."""
    state = load_checkpoint(path)
    model = Examiner(ExaminerConfig.from_dict(state["config"]), exportable=exportable)
    model.load_state_dict(state["model"])
    return model.eval()
