"""Train the Examiner from scratch: Adam on the BCE of sampled pairs, seeded, atomic checkpoints."""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Iterator, NamedTuple

import torch

from trioman.toolkit.examiner.loss import examiner_loss
from trioman.toolkit.examiner.model import Examiner, ExaminerConfig
from trioman.toolkit.examiner.pairs import PAIRINGS, ExaminerBatch, sample_pairs
from trioman.toolkit.train.checkpoint import latest_checkpoint, load_checkpoint, save_checkpoint


@dataclass(frozen=True)
class ExaminerTrainConfig:
    steps: int = 2000
    lr: float = 3e-4
    weight_decay: float = 0.0
    checkpoint_every: int = 250
    keep_checkpoints: int = 2
    seed: int = 0
    pairing: str = "contrast"  # sample_pairs: "contrast" (default) or "paper"

    def __post_init__(self) -> None:
        if self.pairing not in PAIRINGS:
            raise ValueError(f"pairing: expected one of {PAIRINGS}, got {self.pairing!r}")
        if self.steps < 1:
            raise ValueError(f"steps: must be >= 1, got {self.steps}")
        if not self.lr > 0:
            raise ValueError(f"lr: must be > 0, got {self.lr}")
        if self.weight_decay < 0:
            raise ValueError(f"weight_decay: must be >= 0, got {self.weight_decay}")
        if self.checkpoint_every < 1:
            raise ValueError(f"checkpoint_every: must be >= 1, got {self.checkpoint_every}")
        if self.keep_checkpoints < 1:
            raise ValueError(f"keep_checkpoints: must be >= 1, got {self.keep_checkpoints}")

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


class TrainResult(NamedTuple):
    losses: list[float]  # one per step run in this call
    step: int  # the step reached (resumed runs count from their checkpoint)
    checkpoint: Path | None  # the last checkpoint written, if a run folder was given


def _batches(data: Iterable[ExaminerBatch]) -> Iterator[ExaminerBatch]:
    """Cycle a re-iterable source (a list, a DataLoader) forever."""
    while True:
        empty = True
        for batch in data:
            empty = False
            yield batch
        if empty:
            raise ValueError("data: yielded no batch")


def train_examiner(
    model: Examiner,
    data: Iterable[ExaminerBatch],
    config: ExaminerTrainConfig = ExaminerTrainConfig(),
    run: str | os.PathLike | None = None,
) -> TrainResult:
    """Train ``model`` in place for ``config.steps`` steps on pairs drawn by ``sample_pairs``.

    With ``run``, a checkpoint {step, model, config, train, optimizer, rng} is written atomically to
    run/checkpoints every ``checkpoint_every`` steps and at the end, and a run that finds one
    resumes from it (model, optimizer and pair-sampling RNG; ``data`` restarts from its beginning).
    """
    rng = torch.Generator().manual_seed(config.seed)  # the only randomness of the loop: pair sampling
    optimizer = torch.optim.Adam(model.parameters(), lr=config.lr, weight_decay=config.weight_decay)
    step, saved = 0, None
    found = latest_checkpoint(Path(run)) if run is not None else None
    if found is not None:
        state = load_checkpoint(found)
        if state["config"] != model.config.to_dict():
            raise ValueError(f"{found}: checkpoint config {state['config']} differs from the model's {model.config.to_dict()}")
        model.load_state_dict(state["model"])
        optimizer.load_state_dict(state["optimizer"])
        rng.set_state(state["rng"])
        step, saved = int(state["step"]), found
    model.train()
    losses: list[float] = []
    batches = _batches(data)
    while step < config.steps:
        pairs = sample_pairs(next(batches), rng, config.pairing)
        upper, _ = model.branch_logits(pairs.candidate, pairs.reference)
        loss = examiner_loss(upper, pairs.target)
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
        losses.append(loss.item())
        step += 1
        if run is not None and (step % config.checkpoint_every == 0 or step == config.steps):
            state = {
                "step": step,
                "model": model.state_dict(),
                "config": model.config.to_dict(),
                "train": config.to_dict(),
                "optimizer": optimizer.state_dict(),
                "rng": rng.get_state(),
            }
            saved = save_checkpoint(Path(run), step, state, keep=config.keep_checkpoints)
    model.eval()
    return TrainResult(losses, step, saved)


def load_examiner(path: str | os.PathLike, exportable: bool = False) -> Examiner:
    """An Examiner rebuilt from a checkpoint written by ``train_examiner`` (eval mode)."""
    state = load_checkpoint(path)
    model = Examiner(ExaminerConfig.from_dict(state["config"]), exportable=exportable)
    model.load_state_dict(state["model"])
    return model.eval()
