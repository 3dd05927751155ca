"""Examiner network: shapes, score range, the dual-branch wiring, configs and input checks."""

from __future__ import annotations

import dataclasses

import pytest
import torch

from tests.toolkit.examiner.helpers import TINY
from trioman.toolkit.examiner import EXAMINER_CONFIGS, ExaminerConfig, create_examiner, examiner_config, export_inputs
from trioman.toolkit.examiner.model import DualAttention


@pytest.fixture(scope="module")
def model():
    torch.manual_seed(0)
    return create_examiner(TINY).eval()


@pytest.fixture(scope="module")
def detail_model():
    torch.manual_seed(0)
    return create_examiner(TINY, detail_gain=16.0).eval()


def test_shapes(model):
    c, r = export_inputs(model, batch=3)
    feats = model.features(c)
    assert feats.shape == (3, TINY.grid_size**2, TINY.embed_dim)  # class token dropped
    upper, lower = model.branch_logits(c, r)
    for logits in (upper, lower):
        assert logits.scores.shape == logits.weights.shape == (3, TINY.grid_size**2)
    assert model(c, r).shape == (3,)


@pytest.mark.parametrize("detail", [False, True])
@pytest.mark.parametrize("kind", ["black", "white", "noise", "saturated", "out_of_range"])
def test_scores_are_finite_and_in_unit_interval(model, detail_model, kind, detail):
    model = detail_model if detail else model
    g = torch.Generator().manual_seed(1)
    shape = (4, 3, TINY.img_size, TINY.img_size)
    images = {
        "black": torch.zeros(shape),
        "white": torch.ones(shape),
        "noise": torch.rand(shape, generator=g),
        "saturated": torch.eye(3)[torch.arange(4) % 3][:, :, None, None].expand(shape).contiguous(),
        "out_of_range": 1e3 * torch.randn(shape, generator=g),
    }[kind]
    for candidate, reference in [(images, images), (images, torch.rand(shape, generator=g)), (torch.rand(shape, generator=g), images)]:
        score = model(candidate, reference)
        assert torch.isfinite(score).all()
        assert ((score >= 0) & (score <= 1)).all()


def _dual_attention_by_hand(attn: DualAttention, q_src: torch.Tensor, kv_src: torch.Tensor) -> torch.Tensor:
    """Brute-force reference of one branch: Q from q_src, K and V from kv_src ([2, 5, 8], 2 heads)."""
    q = attn.q(q_src).reshape(2, 5, 2, 4).transpose(1, 2)  # [B, h, N, d]
    k, v = attn.kv(kv_src).reshape(2, 5, 2, 2, 4).permute(2, 0, 3, 1, 4)
    if attn.kind == "token":
        out = torch.softmax(q @ k.transpose(-2, -1) / 2.0, dim=-1) @ v  # [N, N] map, d ** -0.5 = 1/2
    else:
        out = torch.empty_like(v)
        for b in range(2):
            for h in range(2):
                qn = q[b, h] / q[b, h].norm(dim=0)  # each channel unit-norm over the patches
                kn = k[b, h] / k[b, h].norm(dim=0)
                logits = torch.tensor([[float((qn[:, i] @ kn[:, j]).detach()) for j in range(4)] for i in range(4)])
                a = torch.softmax(logits * attn.temperature[h, 0, 0], dim=-1)  # [d, d]
                out[b, h] = torch.stack([v[b, h, n] @ a.T for n in range(5)])  # patch n mixes its own channels
    return attn.proj(out.transpose(1, 2).reshape(2, 5, 8))


@pytest.mark.parametrize("kind", ["channel", "token"])
def test_upper_branch_attends_with_the_reference_queries(kind):
    torch.manual_seed(0)
    attn = DualAttention(dim=8, num_heads=2, fused_attn=False, kind=kind)
    if kind == "channel":
        attn.temperature.data = torch.tensor([0.7, 1.9]).reshape(2, 1, 1)
    x_c, x_k = torch.randn(2, 5, 8), torch.randn(2, 5, 8)
    upper, lower = attn(x_c, x_k)
    torch.testing.assert_close(upper, _dual_attention_by_hand(attn, x_k, x_c))  # Q(f_k), K(f_c), V(f_c)
    torch.testing.assert_close(lower, _dual_attention_by_hand(attn, x_k, x_k))  # Q(f_k), K(f_k), V(f_k)


def test_old_configs_load_as_token_attention():
    d = TINY.to_dict()
    del d["dual_attention"]
    assert ExaminerConfig.from_dict(d).dual_attention == "token"
    with pytest.raises(ValueError, match="dual_attention: expected one of"):
        ExaminerConfig(dual_attention="spatial")


@pytest.mark.parametrize("kind", ["channel", "token"])
def test_fused_and_exportable_attention_agree(kind):
    torch.manual_seed(0)
    config = dataclasses.replace(TINY, dual_attention=kind)
    model = create_examiner(config).eval()
    exportable = create_examiner(config, exportable=True).eval()
    exportable.load_state_dict(model.state_dict())
    c, r = export_inputs(model, batch=2)
    torch.testing.assert_close(exportable(c, r), model(c, r), atol=1e-6, rtol=1e-5)


def test_lower_branch_is_the_reference_alone(model):
    c, r = export_inputs(model, batch=2)
    _, lower = model.branch_logits(c, r)
    upper_same, lower_same = model.branch_logits(r, r)
    torch.testing.assert_close(lower.score(), upper_same.score())
    torch.testing.assert_close(lower_same.score(), upper_same.score())


def test_score_depends_on_both_images(model):
    c, r = export_inputs(model, batch=2)
    base = model(c, r)
    assert (model(c, torch.rand_like(r)) - base).abs().min() > 1e-6
    assert (model(torch.rand_like(c), r) - base).abs().min() > 1e-6


def test_named_configs_validate_and_build():
    assert {"examiner_nano", "examiner_tiny", "examiner_small"} <= set(EXAMINER_CONFIGS)
    for config in EXAMINER_CONFIGS.values():
        assert config.img_size == 128 and config.patch_size in (8, 16)
    model = create_examiner("examiner_nano", exportable=True)
    assert model.config == examiner_config("examiner_nano")
    assert ExaminerConfig.from_dict(TINY.to_dict()) == TINY


@pytest.mark.parametrize(
    "field, value",
    [
        ("img_size", 30),  # not a multiple of the patch size
        ("patch_size", 0),
        ("embed_dim", 33),  # not divisible by num_heads
        ("dual_dims", ()),
        ("dual_dims", (15, 8)),  # 15 not divisible by dual_heads
        ("conv_kernel", 2),
        ("mlp_ratio", 0.0),
        ("detail_gain", -1.0),
        ("detail_gain", float("nan")),
        ("detail_sigma", 0.0),
    ],
)
def test_bad_config_names_the_field(field, value):
    with pytest.raises(ValueError, match=rf"^{field.split('[')[0]}"):
        dataclasses.replace(TINY, **{field: value})


def test_unknown_config_name_and_field():
    with pytest.raises(ValueError, match="name: unknown Examiner config 'examiner_huge'"):
        create_examiner("examiner_huge")
    with pytest.raises(ValueError, match=r"config: unknown Examiner config fields \['width'\]"):
        ExaminerConfig.from_dict({**TINY.to_dict(), "width": 3})


def test_bad_inputs_name_the_field(model):
    c, r = export_inputs(model, batch=2)
    with pytest.raises(ValueError, match=r"candidate: expected shape \[B, 3, 32, 32\]"):
        model(c[:, :, :16], r)
    with pytest.raises(ValueError, match=r"reference: expected shape \[B, 3, 32, 32\]"):
        model(c, r[:, :2])
    with pytest.raises(ValueError, match="reference: batch 1 differs from candidate batch 2"):
        model(c, r[:1])
    with pytest.raises(ValueError, match="candidate: contains 1 NaN/Inf values"):
        bad = c.clone()
        bad[0, 0, 0, 0] = float("nan")
        model(bad, r)
    with pytest.raises(ValueError, match="reference: expected a float tensor"):
        model(c, (r * 255).to(torch.uint8))


def test_detail_input_is_the_image_plus_its_unsharp_detail_layer():
    """The ViT's input with detail_gain g: (x - 0.5) / 0.5 + g (x - GaussianBlur(x)), against OpenCV's
    blur (9 taps for sigma 1, edge padding); g = 0 is the plain input, old configs have g = 0."""
    cv2 = pytest.importorskip("cv2")
    import numpy as np

    torch.manual_seed(0)
    config = dataclasses.replace(TINY, detail_gain=8.0, detail_sigma=1.0)
    model = create_examiner(config).eval()
    seen = []
    model.backbone.register_forward_pre_hook(lambda module, args: seen.append(args[0]))
    x = torch.rand(2, 3, TINY.img_size, TINY.img_size, generator=torch.Generator().manual_seed(3))
    model.features(x)
    hwc = x.permute(0, 2, 3, 1).numpy()
    blur = np.stack([cv2.GaussianBlur(im, (9, 9), 1.0, borderType=cv2.BORDER_REPLICATE) for im in hwc])
    expected = (hwc - 0.5) / 0.5 + 8.0 * (hwc - blur)
    np.testing.assert_allclose(seen[0].permute(0, 2, 3, 1).numpy(), expected, atol=1e-5)
    flat = torch.full_like(x, 0.3)  # a flat image has no detail
    model.features(flat)
    torch.testing.assert_close(seen[1], (flat - 0.5) / 0.5)
    plain = create_examiner(TINY)
    plain.backbone.register_forward_pre_hook(lambda module, args: seen.append(args[0]))
    plain.features(x)
    torch.testing.assert_close(seen[2], (x - 0.5) / 0.5)
    assert set(model.state_dict()) == set(plain.state_dict())  # the kernel is derived, not saved
    d = TINY.to_dict()
    del d["detail_gain"], d["detail_sigma"]
    assert ExaminerConfig.from_dict(d).detail_gain == 0.0
