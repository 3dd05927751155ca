"""Refiner loss (paper 3.2.5): L1 + (1 - SSIM) (+ LPIPS) on every output view against its target."""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from trioman.toolkit.metrics import ssim


@dataclass(frozen=True)
class RefinerLossWeights:
    l1: float = 1.0
    ssim: float = 1.0
    lpips: float = 1.0  # used only when an LPIPS module is given (its weights exist locally)

    def __post_init__(self) -> None:
        for name in ("l1", "ssim", "lpips"):
            value = getattr(self, name)
            if not isinstance(value, (int, float)) or not value >= 0:
                raise ValueError(f"{name}: loss weight must be a number >= 0, got {value!r}")


def refiner_loss(
    outputs: torch.Tensor,  # [B, V, 3, H, W]
    targets: torch.Tensor,  # [B, V, 3, H, W]
    lpips: nn.Module | None = None,
    weights: RefinerLossWeights = RefinerLossWeights(),
) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """-> (total, terms). Each term is averaged over images and views (all views weigh the same);
    terms holds the unweighted 'l1', 'ssim' (= 1 - SSIM) and, with an LPIPS module, 'lpips', detached.
    SSIM needs H, W > 5 (11-pixel window, reflect borders); LPIPS-AlexNet needs H, W >= 31."""
    if outputs.ndim != 5 or outputs.shape[2] != 3:
        raise ValueError(f"outputs: expected shape [B, V, 3, H, W], got {tuple(outputs.shape)}")
    if targets.shape != outputs.shape:
        raise ValueError(f"targets: shape {tuple(targets.shape)} differs from outputs {tuple(outputs.shape)}")
    pred = outputs.flatten(0, 1)  # [B * V, 3, H, W]
    gt = targets.flatten(0, 1).to(pred.dtype)
    terms = {"l1": (pred - gt).abs().mean(), "ssim": 1.0 - ssim(pred, gt).mean()}
    total = weights.l1 * terms["l1"] + weights.ssim * terms["ssim"]
    if lpips is not None:
        terms["lpips"] = lpips(pred, gt).mean()
        total = total + weights.lpips * terms["lpips"]
    return total, {k: v.detach() for k, v in terms.items()}
