"""The Refiner's training loop over batches, from scratch: Adam on ``refiner_loss``, in a ``ModelRun``
(toolkit/loops/model_run.py: resume, the non-finite guard, progress, atomic checkpoints).

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

from trioman.toolkit.distributed import MIXED_PRECISION, data_parallel
from trioman.toolkit.loops.checkpoint import load_checkpoint
from trioman.toolkit.loops.settings import check_loop_settings
from trioman.toolkit.loops.guard import StepGuard
from trioman.toolkit.loops.model_run import ModelRun
from trioman.toolkit.refiner.backbones import create_refiner
from trioman.toolkit.refiner.batch import RefinerBatch, check_batch, refiner_inputs, refiner_targets
from trioman.toolkit.refiner.config import RefinerConfig
from trioman.toolkit.refiner.loss import RefinerLossWeights, refiner_loss


@dataclass(frozen=True)
class RefinerTrainConfig:
    steps: int = 2000
    lr: float = 2e-4
    grad_clip: float = 1.0  # max global gradient norm; 0 disables clipping
    checkpoint_every: int = 250
    keep_checkpoints: int = 2
    weights: RefinerLossWeights = field(default_factory=RefinerLossWeights)
    max_skipped: int = 10  # consecutive steps with a non-finite loss or gradient that stop the run
    mixed_precision: str = "no"  # "bf16": forward and loss under torch.autocast (bf16 needs no loss scaling)
    gradient_checkpointing: bool = False  # recompute activations in backward (models with enable_gradient_checkpointing)

    def __post_init__(self) -> None:
        if not isinstance(self.steps, int) or self.steps < 1:
            raise ValueError(f"steps: must be a positive integer, got {self.steps!r}")
        if not self.lr > 0:
            raise ValueError(f"lr: must be > 0, got {self.lr}")
        if not self.grad_clip >= 0:
            raise ValueError(f"grad_clip: must be >= 0, got {self.grad_clip}")
        check_loop_settings(self)
        if self.mixed_precision not in MIXED_PRECISION:
            raise ValueError(f"mixed_precision: expected one of {MIXED_PRECISION}, got {self.mixed_precision!r}")
        if not isinstance(self.gradient_checkpointing, bool):
            raise ValueError(f"gradient_checkpointing: must be a bool, got {self.gradient_checkpointing!r}")

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


class RefinerTrainResult(NamedTuple):
    losses: list[float]  # total loss of each step of this call that updated the model (skipped ones excluded)
    step: int  # the step reached (a resumed run counts from its checkpoint)
    checkpoint: Path | None  # the last checkpoint written or resumed from, if a run folder was given
    skipped: int = 0  # steps skipped for a non-finite loss or gradient, over the whole run


def train_step(
    model: nn.Module,
    optimizer: torch.optim.Optimizer,
    batch: RefinerBatch,
    weights: RefinerLossWeights = RefinerLossWeights(),
    lpips: nn.Module | None = None,
    grad_clip: float = 1.0,
    guard: StepGuard | None = None,
    step: int = 0,
    mixed_precision: str = "no",
    net: nn.Module | None = None,
) -> dict[str, float] | None:
    """One optimisation step on ``batch`` (moved to the model's device) -> {'total', 'l1', 'ssim'[, 'lpips']}
    (before the step). ``mixed_precision`` "bf16" runs the forward and the loss under torch.autocast.
    ``net`` runs the forward when given: ``model`` under DDP (toolkit/distributed.py).

    With ``guard``, a non-finite loss or gradient skips the update (the guard counts it; ``step`` names
    it in its message) and returns None."""
    check_batch(batch)
    device = next(model.parameters()).device
    batch = RefinerBatch(*(None if x is None else x.to(device) for x in batch))
    conditions = model.config.conditions
    optimizer.zero_grad(set_to_none=True)
    hint = f"Lower the learning rate (lr={optimizer.param_groups[0]['lr']:g}) or check the data."
    with torch.autocast(device.type, dtype=torch.bfloat16, enabled=mixed_precision == "bf16"):
        outputs = (model if net is None else net)(*refiner_inputs(batch, conditions))
        if guard is not None and not guard.finite_ok(outputs, step, "output", hint):  # the loss refuses NaN images
            return None
        total, terms = refiner_loss(outputs.float(), refiner_targets(batch, conditions), lpips=lpips, weights=weights)
    if guard is not None and not guard.finite_ok(total, step, "loss", hint):
        return None
    total.backward()
    if guard is not None and not guard.grads_ok(model.parameters(), step, hint):
        optimizer.zero_grad(set_to_none=True)
        return None
    if grad_clip > 0:
        nn.utils.clip_grad_norm_(model.parameters(), grad_clip)
    optimizer.step()
    return {"total": float(total.detach()), **{k: float(v) for k, v in terms.items()}}


def refiner_loop(
    model: nn.Module,
    batches: Callable[[int], RefinerBatch],
    config: RefinerTrainConfig = RefinerTrainConfig(),
    run: str | os.PathLike | None = None,
    lpips: nn.Module | None = None,
    progress: bool = False,
) -> RefinerTrainResult:
    """Train ``model`` in place (on its device) for ``config.steps`` steps, step s on ``batches(s)``;
    ``progress`` shows a bar with the loss (on a terminal only). Parameters without ``requires_grad``
    (the sd-turbo backbone's VAE encoder) stay frozen.

    With ``run``, a checkpoint {step, model, config, train, optimizer} is written atomically to
    run/checkpoints every ``checkpoint_every`` steps and at the end, and a run that finds one resumes
    from it. ``lpips`` (e.g. ``trioman.toolkit.lpips.load_lpips()``, None when its weights are absent)
    adds the LPIPS term. A step with a non-finite loss or gradient is skipped and counted
    (``RefinerTrainResult.skipped``, kept in the checkpoints); ``config.max_skipped`` consecutive ones
    raise ``NonFiniteError``; a checkpoint is never written from non-finite weights.

    Under torchrun (toolkit/distributed.py) ``batches(s)`` is this rank's share of step s, DDP averages
    the gradients, rank 0 alone writes checkpoints and shows progress, and a checkpoint resumes only
    at the world size that wrote it.
    """
    if config.gradient_checkpointing:
        if not hasattr(model, "enable_gradient_checkpointing"):
            raise ValueError(f"gradient_checkpointing: the {model.config.backbone!r} backbone does not support it")
        model.enable_gradient_checkpointing()
    optimizer = torch.optim.Adam([p for p in model.parameters() if p.requires_grad], lr=config.lr)
    loop = ModelRun("refiner", "Refiner", model, optimizer, config, run, progress)
    model.train()
    net = data_parallel(model)
    while loop.running:
        terms = train_step(model, optimizer, batches(loop.step), config.weights, lpips, config.grad_clip, loop.guard,
                           loop.step, config.mixed_precision, net)
        if loop.advance(None if terms is None else terms["total"]) and run is not None:
            loop.check_weights()
            loop.save(loop.state())
    loop.finish()
    return RefinerTrainResult(loop.losses, loop.step, loop.saved, loop.guard.skipped)


def load_refiner(path: str | os.PathLike, exportable: bool = False) -> nn.Module:
    """A Refiner rebuilt from a checkpoint written by ``refiner_loop`` (eval mode)."""
    state = load_checkpoint(path)
    model = create_refiner(RefinerConfig.from_dict(state["config"]), exportable=exportable, seed=None)
    model.load_state_dict(state["model"])
    return model.eval()
