"""Train the Refiner from scratch: Adam on ``refiner_loss``, atomic resumable checkpoints.

Determinism: the loop draws no random numbers. The batch of step s is ``batches(s)`` (so a resumed
run sees exactly the batches it would have seen), and the initial weights come from
``create_refiner(config, seed=...)``; the same seed and the same batches give the same weights.
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, NamedTuple

import torch
from torch import nn
from tqdm import tqdm

from trioman.toolkit.refiner.backbones import create_refiner
from trioman.toolkit.refiner.batch import RefinerBatch, check_batch, refiner_inputs, refiner_targets
from trioman.toolkit.refiner.config import RefinerConfig
from trioman.toolkit.refiner.loss import RefinerLossWeights, refiner_loss
from trioman.toolkit.train.checkpoint import latest_checkpoint, load_checkpoint, save_checkpoint


@dataclass(frozen=True)
class RefinerTrainConfig:
    steps: int = 2000
    lr: float = 2e-4
    grad_clip: float = 1.0  # max global gradient norm; 0 disables clipping
    checkpoint_every: int = 250
    keep_checkpoints: int = 2
    weights: RefinerLossWeights = field(default_factory=RefinerLossWeights)

    def __post_init__(self) -> None:
        if not isinstance(self.steps, int) or self.steps < 1:
            raise ValueError(f"steps: must be a positive integer, got {self.steps!r}")
        if not self.lr > 0:
            raise ValueError(f"lr: must be > 0, got {self.lr}")
        if not self.grad_clip >= 0:
            raise ValueError(f"grad_clip: must be >= 0, got {self.grad_clip}")
        if self.checkpoint_every < 1:
            raise ValueError(f"checkpoint_every: must be >= 1, got {self.checkpoint_every}")
        if self.keep_checkpoints < 1:
            raise ValueError(f"keep_checkpoints: must be >= 1, got {self.keep_checkpoints}")

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


class RefinerTrainResult(NamedTuple):
    losses: list[float]  # total loss of each step run in this call
    step: int  # the step reached (a resumed run counts from its checkpoint)
    checkpoint: Path | None  # the last checkpoint written or resumed from, if a run folder was given


def train_step(
    model: nn.Module,
    optimizer: torch.optim.Optimizer,
    batch: RefinerBatch,
    weights: RefinerLossWeights = RefinerLossWeights(),
    lpips: nn.Module | None = None,
    grad_clip: float = 1.0,
) -> dict[str, float]:
    """One optimisation step on ``batch`` -> {'total', 'l1', 'ssim'[, 'lpips']} (before the step)."""
    check_batch(batch)
    conditions = model.config.conditions
    outputs = model(*refiner_inputs(batch, conditions))
    total, terms = refiner_loss(outputs, refiner_targets(batch, conditions), lpips=lpips, weights=weights)
    optimizer.zero_grad(set_to_none=True)
    total.backward()
    if grad_clip > 0:
        nn.utils.clip_grad_norm_(model.parameters(), grad_clip)
    optimizer.step()
    return {"total": float(total.detach()), **{k: float(v) for k, v in terms.items()}}


def train_refiner(
    model: nn.Module,
    batches: Callable[[int], RefinerBatch],
    config: RefinerTrainConfig = RefinerTrainConfig(),
    run: str | os.PathLike | None = None,
    lpips: nn.Module | None = None,
    progress: bool = False,
) -> RefinerTrainResult:
    """Train ``model`` in place for ``config.steps`` steps, step s on ``batches(s)``; ``progress``
    shows a bar with the loss (on a terminal only).

    With ``run``, a checkpoint {step, model, config, train, optimizer} is written atomically to
    run/checkpoints every ``checkpoint_every`` steps and at the end, and a run that finds one resumes
    from it. ``lpips`` (e.g. ``trioman.toolkit.lpips.load_lpips()``, None when its weights are absent)
    adds the LPIPS term.
    """
    optimizer = torch.optim.Adam(model.parameters(), lr=config.lr)
    step, saved = 0, None
    found = latest_checkpoint(Path(run)) if run is not None else None
    if found is not None:
        state = load_checkpoint(found)
        if state["config"] != model.config.to_dict():
            raise ValueError(f"{found}: checkpoint config {state['config']} differs from the model's {model.config.to_dict()}")
        model.load_state_dict(state["model"])
        optimizer.load_state_dict(state["optimizer"])
        step, saved = int(state["step"]), found
    model.train()
    losses: list[float] = []
    bar = tqdm(total=config.steps, initial=step, desc="refiner", unit="step", disable=None if progress else True)
    while step < config.steps:
        losses.append(train_step(model, optimizer, batches(step), config.weights, lpips, config.grad_clip)["total"])
        step += 1
        bar.update(1)
        bar.set_postfix(loss=f"{losses[-1]:.4f}")
        if run is not None and (step % config.checkpoint_every == 0 or step == config.steps):
            state = {
                "step": step,
                "model": model.state_dict(),
                "config": model.config.to_dict(),
                "train": config.to_dict(),
                "optimizer": optimizer.state_dict(),
            }
            saved = save_checkpoint(Path(run), step, state, keep=config.keep_checkpoints)
    bar.close()
    model.eval()
    return RefinerTrainResult(losses, step, saved)


def load_refiner(path: str | os.PathLike, exportable: bool = False) -> nn.Module:
    """A Refiner rebuilt from a checkpoint written by ``train_refiner`` (eval mode)."""
    state = load_checkpoint(path)
    model = create_refiner(RefinerConfig.from_dict(state["config"]), exportable=exportable, seed=None)
    model.load_state_dict(state["model"])
    return model.eval()
