"""Non-finite guards for training loops: a step whose loss or gradient is NaN or Inf is skipped (no
update) and counted; repeated failures stop the run with a message; weights that are not finite are
never written to a checkpoint, so the last good one stays the newest. Under torchrun the skip decision
is all-reduced: a step is skipped on every rank when one rank sees a NaN/Inf (toolkit/distributed.py)."""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import torch

from trioman.toolkit.distributed import all_ranks


class NonFiniteError(FloatingPointError):
    """Training stopped: too many consecutive non-finite steps, or non-finite weights."""


def grads_finite(params: Iterable[torch.nn.Parameter]) -> bool:
    """Every gradient present is finite (one reduction per tensor, one sync)."""
    norms = [torch.linalg.vector_norm(p.grad.detach()) for p in params if p.grad is not None]
    return not norms or bool(torch.isfinite(torch.stack(norms)).all())


def weights_finite(module: torch.nn.Module) -> bool:
    """Every parameter and buffer of ``module`` is finite."""
    tensors = [t.detach() for t in (*module.parameters(), *module.buffers()) if t.is_floating_point()]
    return not tensors or bool(torch.isfinite(torch.stack([torch.linalg.vector_norm(t) for t in tensors])).all())


class StepGuard:
    """Decides, per step, whether the optimizer may update, and counts the steps it skips.

    ``name`` labels the messages ("refiner", "examiner"); ``max_consecutive`` consecutive skipped steps
    raise :class:`NonFiniteError`; ``skipped`` starts from a resumed run's count.
    """

    def __init__(self, name: str, max_consecutive: int, skipped: int = 0) -> None:
        if not isinstance(max_consecutive, int) or max_consecutive < 1:
            raise ValueError(f"max_consecutive: must be a positive integer, got {max_consecutive!r}")
        self.name = name
        self.max_consecutive = max_consecutive
        self.skipped = skipped  # every skipped step of the run
        self.consecutive = 0

    def finite_ok(self, value: torch.Tensor, step: int, what: str = "loss", hint: str = "") -> bool:
        """Before backward: False (the step counted as skipped) when ``value`` (the loss, or a model
        output the loss would refuse) holds a NaN or Inf on any rank."""
        if all_ranks(bool(torch.isfinite(value.detach()).all())):
            return True
        self._skip(step, what, hint)
        return False

    def grads_ok(self, params: Iterable[torch.nn.Parameter], step: int, hint: str = "") -> bool:
        """After backward: False (the step counted as skipped) when a gradient is NaN or Inf on any rank;
        True resets the consecutive count."""
        if not all_ranks(grads_finite(params)):
            self._skip(step, "gradient", hint)
            return False
        self.consecutive = 0
        return True

    def _skip(self, step: int, what: str, hint: str) -> None:
        self.skipped += 1
        self.consecutive += 1
        if self.consecutive >= self.max_consecutive:
            raise NonFiniteError(
                f"{self.name}: {self.consecutive} consecutive steps (the last, step {step + 1}, with a non-finite {what}) "
                f"were skipped; the run stops ({self.skipped} skipped in all). {hint}".rstrip())


def check_weights(module: torch.nn.Module, name: str, step: int, last_good: Path | None) -> None:
    """Before writing a checkpoint: NonFiniteError when a weight is NaN or Inf (nothing is written;
    ``last_good`` is named as the checkpoint to go back to)."""
    if not weights_finite(module):
        where = f"the last good checkpoint is {last_good}" if last_good is not None else "no checkpoint was written"
        raise NonFiniteError(f"{name}: the weights at step {step} are not finite; the run stops without saving them "
                             f"({where})")
