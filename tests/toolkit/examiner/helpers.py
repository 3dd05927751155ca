"""Small Examiner configs and a synthetic pair task for the tests."""

from __future__ import annotations

import torch
import torch.nn.functional as F

from trioman.toolkit.examiner import ExaminerBatch, ExaminerConfig

TINY = ExaminerConfig(img_size=32, patch_size=8, embed_dim=32, depth=1, num_heads=2, dual_dims=(16, 8), dual_heads=2, head_hidden=16)


def texture(n: int, size: int, g: torch.Generator) -> torch.Tensor:
    """[n, 3, size, size] random colour texture: coarse colour cells plus fine noise, in [0, 1]."""
    cells = torch.rand(n, 3, size // 4, size // 4, generator=g)
    base = F.interpolate(cells, size=(size, size), mode="bilinear", align_corners=False)
    return (0.8 * base + 0.2 * torch.rand(n, 3, size, size, generator=g)).clamp(0, 1)


def real_copy(x: torch.Tensor, g: torch.Generator) -> torch.Tensor:
    """Another 'real' view: shifted by up to 2 px, with mild noise."""
    dx, dy = (int(v) for v in torch.randint(-2, 3, (2,), generator=g))
    return (torch.roll(x, (dy, dx), dims=(2, 3)) + 0.02 * torch.randn(x.shape, generator=g)).clamp(0, 1)


def coarse_copy(x: torch.Tensor, g: torch.Generator) -> torch.Tensor:
    """A 'coarse render': blurred and colour-shifted per image."""
    blurred = F.avg_pool2d(F.pad(x, (2, 2, 2, 2), mode="replicate"), 5, stride=1)
    shift = 0.25 * (torch.rand(x.shape[0], 3, 1, 1, generator=g) - 0.5)
    return (blurred + shift).clamp(0, 1)


def synthetic_batch(n: int, size: int, g: torch.Generator) -> ExaminerBatch:
    """(I^T, I_c^T, I^{T+k}): gt and reference are real views of one texture, coarse a render of gt."""
    tex = texture(n, size, g)
    gt = real_copy(tex, g)
    return ExaminerBatch(gt=gt, coarse=coarse_copy(gt, g), reference=real_copy(tex, g))
