"""A model's training run in a run folder, the part every training loop shares (the avatar's, the Refiner's, the
Examiner's): resume from the newest checkpoint, the non-finite guard, the progress bar and a checkpoint at each
boundary (written by rank 0 alone, never from non-finite weights)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Protocol

import torch
from torch import nn
from tqdm import tqdm

from trioman.toolkit.distributed import barrier, check_world_size, current
from trioman.toolkit.loops.checkpoint import check_config, latest_checkpoint, load_checkpoint, save_checkpoint
from trioman.toolkit.loops.guard import StepGuard, check_weights


class LoopConfig(Protocol):
    """The fields of a loop's config that its run reads (``RefinerTrainConfig``, ``ExaminerTrainConfig``;
    ``TrainConfig``, the avatar's, names its length ``iterations`` and passes it as ``ModelRun(steps=...)``)."""

    steps: int
    checkpoint_every: int
    keep_checkpoints: int
    max_skipped: int

    def to_dict(self) -> dict[str, Any]: ...


class ModelRun:
    """One call of a model's training loop: where it stands (``step``, ``saved``, ``guard``, ``losses``), and
    how it resumes, shows progress and saves.

    ``model`` and ``optimizer`` resume from the newest checkpoint of ``run`` when there is one; ``resumed`` is
    that checkpoint ({} for a fresh run) for the loop's own entries (an RNG, a selection). A checkpoint of
    another model config is refused (``ConfigMismatch`` naming ``what``, e.g. "Refiner"), and so is one
    written at another world size. ``name`` labels the guard's messages and the bar, shown with
    ``progress`` on rank 0 (on a terminal only), counting in ``unit``.

    The avatar's loop (``toolkit.train.loop``) keeps a run record of its own, run/config.json, and says so with
    keywords: ``what`` None (the caller has checked the run's config: the checkpoint's is not compared),
    ``resume`` False for a run not asked to resume (no checkpoint is looked for), ``steps`` the run's length
    (None: ``config.steps``) and ``open_bar`` False to open the bar later, with ``open_bar()``, once the run
    is there (else the first ``advance`` opens it).
    """

    def __init__(self, name: str, what: str | None, model: nn.Module, optimizer: torch.optim.Optimizer,
                 config: LoopConfig, run: str | os.PathLike | None, progress: bool, *, steps: int | None = None,
                 resume: bool = True, unit: str = "step", open_bar: bool = True) -> None:
        self.model, self.optimizer, self.config = model, optimizer, config
        self.steps = config.steps if steps is None else steps
        self.run = None if run is None else Path(run)
        self.ranks = current()
        self.step, self.saved, skipped, self.resumed = 0, None, 0, {}
        found = latest_checkpoint(self.run) if self.run is not None and resume else None
        if found is not None:
            state = load_checkpoint(found)
            if what is not None:
                check_config(found, state["config"], model.config.to_dict(), what)
            check_world_size(int(state.get("world_size", 1)), self.ranks, found)
            model.load_state_dict(state["model"])
            optimizer.load_state_dict(state["optimizer"])
            self.step, self.saved, skipped, self.resumed = int(state["step"]), found, int(state.get("skipped", 0)), state
        self.guard = StepGuard(name, config.max_skipped, skipped)
        self.losses: list[float] = []  # one per step of this call that updated the model
        self._progress, self._unit, self._bar = progress, unit, None
        if open_bar:
            self.open_bar()

    def open_bar(self) -> tqdm:
        """The progress bar, opened now if it is not open yet."""
        if self._bar is None:
            self._bar = tqdm(total=self.steps, initial=self.step, desc=self.guard.name, unit=self._unit,
                             disable=None if self._progress and self.ranks.main else True)
        return self._bar

    @property
    def running(self) -> bool:
        return self.step < self.steps

    def advance(self, loss: float | None, **shown: str) -> bool:
        """Count a step (``loss`` None when the guard skipped it) and show it, with ``shown`` after the loss ->
        whether the step ends at a checkpoint boundary (every ``checkpoint_every`` steps, and the last)."""
        if loss is not None:
            self.losses.append(loss)
        self.step += 1
        bar = self.open_bar()
        bar.update(1)
        bar.set_postfix(loss=f"{self.losses[-1]:.4f}" if self.losses else "-", **shown,
                        **({"skipped": self.guard.skipped} if self.guard.skipped else {}))
        return self.step % self.config.checkpoint_every == 0 or self.step == self.steps

    def check_weights(self) -> None:
        """Before a checkpoint or a validation: ``NonFiniteError`` when a weight is NaN or Inf."""
        check_weights(self.model, self.guard.name, self.step, self.saved)

    def state(self, **entries: Any) -> dict[str, Any]:
        """This step's checkpoint: {step, model, config, train, optimizer, **entries, skipped, world_size}."""
        return {"step": self.step, "model": self.model.state_dict(), "config": self.model.config.to_dict(),
                "train": self.config.to_dict(), "optimizer": self.optimizer.state_dict(), **entries,
                "skipped": self.guard.skipped, "world_size": self.ranks.world_size}

    def save(self, state: dict[str, Any]) -> None:
        """Write ``state`` atomically to run/checkpoints on rank 0, keeping the newest ``keep_checkpoints``."""
        if self.ranks.main:
            self.saved = save_checkpoint(self.run, self.step, state, keep=self.config.keep_checkpoints)

    def finish(self) -> None:
        """Close the bar, put the model in eval mode and wait for every rank."""
        self.open_bar().close()
        self.model.eval()
        barrier()
