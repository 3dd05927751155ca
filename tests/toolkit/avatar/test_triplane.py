"""The triplane's sparse sampling and texel layer against grid_sample and a linear layer on its features."""

import torch
import torch.nn.functional as F
from hypothesis import given, settings
from hypothesis import strategies as st

from trioman.toolkit.avatar.triplane import Triplane


def _triplane(channels: int = 5, res: int = 7) -> Triplane:
    torch.manual_seed(0)
    return Triplane(channels, res, torch.tensor([0.1, -0.2, 0.3]), 0.8)


def _dense(tp: Triplane, points: torch.Tensor) -> torch.Tensor:
    """sampling() as a dense [N, 3 R^2] matrix."""
    indices, weights, texels = tp.sampling(points)
    return torch.zeros(points.shape[0], texels).scatter_add_(1, indices, weights)


def _edge_points() -> torch.Tensor:
    """Points inside, on the faces and corners of the cube, and outside it (clamped onto it)."""
    tp = _triplane()
    torch.manual_seed(1)
    inside = tp.center + tp.half_size * (2 * torch.rand(50, 3) - 1)
    corners = tp.center + tp.half_size * torch.tensor([[1.0, 1.0, 1.0], [-1.0, -1.0, -1.0], [1.0, -1.0, 0.0]])
    outside = tp.center + tp.half_size * torch.tensor([[3.0, -5.0, 0.2], [0.0, 0.0, 1.5]])
    return torch.cat([inside, corners, outside])


def test_sampling_is_grid_sample():
    tp = _triplane()
    points = _edge_points()
    _, c, r, _ = tp.planes.shape
    flat = tp.planes.detach().permute(0, 2, 3, 1).reshape(3, r * r, c)  # texels by plane, row, column
    dense = _dense(tp, points).view(-1, 3, r * r)
    sampled = torch.cat([dense[:, k] @ flat[k] for k in range(3)], 1)  # [N, 3C]
    torch.testing.assert_close(sampled, tp(points).detach(), atol=1e-6, rtol=0)
    indices, weights, _ = tp.sampling(points)
    assert bool((indices >= 0).all()) and bool((indices < tp.texels).all())
    torch.testing.assert_close(weights.view(-1, 3, 4).sum(-1), torch.ones(points.shape[0], 3))


@settings(max_examples=25, deadline=None)
@given(st.lists(st.floats(-1e6, 1e6, allow_nan=False), min_size=3, max_size=3), st.integers(2, 9))
def test_sampling_of_any_point_is_a_convex_blend_of_texels(xyz, res):
    tp = _triplane(res=res)
    indices, weights, texels = tp.sampling(torch.tensor([xyz], dtype=torch.float32))
    assert bool((indices >= 0).all()) and bool((indices < texels).all())
    assert bool((weights >= 0).all())
    torch.testing.assert_close(weights.view(3, 4).sum(-1), torch.ones(3))


def test_texel_layer_then_sampling_is_the_layer_on_the_features():
    tp = _triplane()
    points = _edge_points()
    weight = torch.randn(6, tp.out_dim, requires_grad=True)
    grad_out = torch.randn(points.shape[0], 6)
    results = []
    for texel_first in (False, True):
        if texel_first:
            out = _dense(tp, points) @ tp.texel_layer(weight)
        else:
            out = F.linear(tp(points), weight)
        planes_grad, weight_grad = torch.autograd.grad(out, (tp.planes, weight), grad_out)
        results.append((out.detach(), planes_grad, weight_grad))
    for a, b in zip(*results):
        torch.testing.assert_close(a, b, atol=1e-5, rtol=1e-5)
