"""Torch avatars for the export tests and the tests built on exported avatars: a small model with every weight
perturbed. Import it after ``pytest.importorskip("torch")``."""

import torch

from tests.toolkit.avatar.factories import grid_mesh
from trioman.toolkit.avatar.model import AvatarConfig, GaussianAvatar


def trained_like(cfg: AvatarConfig, seed: int = 0) -> GaussianAvatar:
    """A small avatar with every weight perturbed (fresh output layers are zero and would hide errors)."""
    model = GaussianAvatar(grid_mesh(), cfg)
    gen = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for p in model.parameters():
            p.add_(0.3 * torch.randn(p.shape, generator=gen))
    return model.eval()
