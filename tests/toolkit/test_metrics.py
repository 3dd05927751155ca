"""PSNR / SSIM / compositing / the masked evaluation protocol against independent references.

SSIM references: skimage.metrics.structural_similarity(gaussian_weights=True, sigma=1.5,
use_sample_covariance=False, data_range=1, channel_axis) is the 'valid' border convention
(torchmetrics <= 1.4); torchmetrics >= 1.5 ('reflect', our default) is skimage's full SSIM map of the
images reflect-padded by the window radius (numpy 'reflect' == torch 'reflect'), cropped back to
H x W: the padded border pixels then use windows that never reach skimage's own padding.
"""

import numpy as np
import pytest

torch = pytest.importorskip("torch")
from hypothesis import given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402
from skimage.metrics import structural_similarity as sk_ssim  # noqa: E402

from trioman.toolkit.metrics import (  # noqa: E402
    PSNR_MAX_DB,
    FrameMetrics,
    composite_on,
    evaluate_batch,
    evaluate_pair,
    gaussian_window_size,
    psnr,
    ssim,
    ssim_map,
)

SK = dict(gaussian_weights=True, sigma=1.5, use_sample_covariance=False, data_range=1.0, channel_axis=2)


def nchw(*imgs_hwc: np.ndarray) -> "torch.Tensor":
    return torch.from_numpy(np.stack(imgs_hwc)).permute(0, 3, 1, 2).contiguous()


def sk_reflect(a: np.ndarray, b: np.ndarray, r: int = 5) -> float:
    pad = ((r, r), (r, r), (0, 0))
    _, S = sk_ssim(np.pad(a, pad, mode="reflect"), np.pad(b, pad, mode="reflect"), full=True, **SK)
    return float(S[r:-r, r:-r].mean())


def structured_pairs(seed: int = 0) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """Random and structured HWC float64 image pairs of assorted (non-square) sizes."""
    rng = np.random.default_rng(seed)
    out = []
    a = rng.random((40, 52, 3))
    out.append(("noise/noise", a, rng.random(a.shape)))
    out.append(("noise/noisy", a, np.clip(a + 0.1 * rng.standard_normal(a.shape), 0, 1)))
    yy, xx = np.mgrid[0:64, 0:48] / 64.0
    ramp = np.stack([yy, xx, 0.5 * (yy + xx)], axis=-1)
    out.append(("ramp/shifted", ramp, np.clip(ramp * 0.8 + 0.1, 0, 1)))
    checker = ((np.indices((33, 45)).sum(0) // 4) % 2).astype(np.float64)[..., None].repeat(3, -1)
    out.append(("checker/blurred", checker, 0.25 + 0.5 * checker))
    # an "avatar" on white: a shaded blob, and a slightly shifted, recoloured prediction
    yy, xx = np.mgrid[0:56, 0:40]
    blob = (((yy - 28) / 20.0) ** 2 + ((xx - 20) / 12.0) ** 2 < 1.0)[..., None]
    tex = 0.5 + 0.4 * np.sin(np.stack([yy / 3.0, xx / 5.0, (yy + xx) / 7.0], -1))
    gt = np.where(blob, tex, 1.0)
    pred = np.where(np.roll(blob, 2, axis=1), np.clip(tex * 0.9 + 0.05, 0, 1), 1.0)
    out.append(("avatar/shifted", gt, pred))
    out.append(("black/white", np.zeros((24, 24, 3)), np.ones((24, 24, 3))))
    out.append(("const/noise", np.full((24, 30, 3), 0.3), rng.random((24, 30, 3))))
    return out


# ------------------------------------------------------------------------------------------- PSNR


def test_psnr_matches_numpy():
    rng = np.random.default_rng(1)
    a, b = rng.random((2, 3, 3, 20, 24))
    got = psnr(torch.from_numpy(a), torch.from_numpy(b)).numpy()
    mse = ((a - b) ** 2).reshape(3, -1).mean(1)
    np.testing.assert_allclose(got, 10 * np.log10(1.0 / mse), rtol=1e-12)


def test_psnr_masked_matches_numpy_binary_and_soft():
    rng = np.random.default_rng(2)
    a, b = rng.random((2, 2, 3, 16, 18))
    binary = (rng.random((2, 1, 16, 18)) > 0.6).astype(np.float64)
    soft = rng.random((2, 1, 16, 18))
    for m in (binary, soft):
        got = psnr(torch.from_numpy(a), torch.from_numpy(b), torch.from_numpy(m)).numpy()
        w = np.broadcast_to(m, a.shape)
        mse = (w * (a - b) ** 2).reshape(2, -1).sum(1) / w.reshape(2, -1).sum(1)
        np.testing.assert_allclose(got, 10 * np.log10(1.0 / mse), rtol=1e-12)
    # a binary mask = PSNR over the selected pixels only; differences outside it are ignored
    b2 = b.copy()
    b2[np.broadcast_to(binary, b.shape) == 0] = 0.0
    np.testing.assert_allclose(
        psnr(torch.from_numpy(a), torch.from_numpy(b2), torch.from_numpy(binary)).numpy(),
        psnr(torch.from_numpy(a), torch.from_numpy(b), torch.from_numpy(binary)).numpy(),
    )


def test_psnr_identical_is_capped_and_errors_are_clear():
    x = torch.rand(2, 3, 8, 8)
    assert torch.equal(psnr(x, x.clone()), torch.full((2,), PSNR_MAX_DB))
    mask = torch.ones(2, 1, 8, 8)
    mask[1] = 0
    with pytest.raises(ValueError, match=r"mask: empty .*\[1\]"):
        psnr(x, x + 0.1, mask)
    with pytest.raises(ValueError, match="shapes differ"):
        psnr(x, x[:, :, :4])
    bad = x.clone()
    bad[0, 0, 0, 0] = float("nan")
    with pytest.raises(ValueError, match="gt: 1 non-finite"):
        psnr(x, bad)
    with pytest.raises(ValueError, match=r"pred: expected shape \[B, C, H, W\]"):
        psnr(x[0], x[0])
    with pytest.raises(ValueError, match=r"mask: values must lie in \[0, 1\]"):
        psnr(x, x, mask * 2 + 0.5)
    with pytest.raises(ValueError, match=r"mask: expected shape \[2, 1, 8, 8\]"):
        psnr(x, x, torch.ones(2, 2, 8, 8))


# ------------------------------------------------------------------------------------------- SSIM


def test_gaussian_window_size_like_torchmetrics():
    assert gaussian_window_size(1.5) == 11
    assert gaussian_window_size(1.0) == 9


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_ssim_valid_matches_skimage(dtype):
    tol = 1e-10 if dtype == torch.float64 else 2e-6
    for name, a, b in structured_pairs():
        ref = sk_ssim(a, b, **SK)
        got = ssim(nchw(a).to(dtype), nchw(b).to(dtype), border="valid").item()
        assert abs(got - ref) <= tol, f"{name}: ours {got:.8f} skimage {ref:.8f}"


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_ssim_reflect_matches_skimage_on_reflect_padded_images(dtype):
    tol = 1e-10 if dtype == torch.float64 else 2e-6
    for name, a, b in structured_pairs(3):
        ref = sk_reflect(a, b)
        got = ssim(nchw(a).to(dtype), nchw(b).to(dtype)).item()
        assert abs(got - ref) <= tol, f"{name}: ours {got:.8f} reference {ref:.8f}"


def test_ssim_other_sigma_and_explicit_window():
    rng = np.random.default_rng(4)
    a = rng.random((30, 34, 3))
    b = np.clip(a + 0.2 * rng.standard_normal(a.shape), 0, 1)
    ref = sk_ssim(a, b, **{**SK, "sigma": 1.0})
    assert abs(ssim(nchw(a), nchw(b), window=None, sigma=1.0, border="valid").item() - ref) < 1e-10
    ref7 = sk_ssim(a, b, **{**SK, "sigma": 1.0}, win_size=7)  # skimage crops by win_size, filters with r=4
    assert np.isfinite(ref7)
    m = ssim_map(nchw(a), nchw(b), window=7, sigma=1.0, border="valid")
    assert m.shape == (1, 3, 24, 28)


def test_ssim_batch_is_per_image():
    pairs = structured_pairs(5)[:2]
    a = nchw(*[p[1] for p in pairs])
    b = nchw(*[p[2] for p in pairs])
    got = ssim(a, b)
    for i in range(2):
        assert abs(got[i].item() - ssim(a[i : i + 1], b[i : i + 1]).item()) < 1e-12
    assert ssim_map(a, b).shape == a.shape


@pytest.mark.parametrize("value", [0.0, 1.0, 0.37])
def test_ssim_identical_images_give_one(value):
    const = torch.full((1, 3, 20, 20), value)
    noise = torch.rand(2, 3, 20, 23, generator=torch.Generator().manual_seed(0))
    for x in (const, noise):
        for border in ("reflect", "valid"):
            assert torch.allclose(ssim(x, x.clone(), border=border), torch.ones(x.shape[0]), atol=1e-6)


def test_ssim_errors():
    x = torch.rand(1, 3, 8, 8)
    with pytest.raises(ValueError, match="window"):
        ssim(x, x, window=4)
    with pytest.raises(ValueError, match="smaller than the SSIM window"):
        ssim(x, x, border="valid")
    with pytest.raises(ValueError, match="border"):
        ssim(x, x, border="same")
    with pytest.raises(ValueError, match="sigma"):
        ssim(x, x, sigma=0.0)


# A pool of extreme images: all black, all white, constants, near-constants, noise, binary noise.
def _extreme(kind: str, seed: int, shape=(1, 3, 16, 16)) -> "torch.Tensor":
    g = torch.Generator().manual_seed(seed)
    if kind == "black":
        return torch.zeros(shape)
    if kind == "white":
        return torch.ones(shape)
    if kind == "const":
        return torch.full(shape, torch.rand(1, generator=g).item())
    if kind == "near_const":
        return (0.5 + 1e-6 * torch.rand(shape, generator=g)).clamp(0, 1)
    if kind == "binary":
        return (torch.rand(shape, generator=g) > 0.5).float()
    return torch.rand(shape, generator=g)


KINDS = ["black", "white", "const", "near_const", "binary", "noise"]


@settings(max_examples=60, deadline=None)
@given(
    st.sampled_from(KINDS),
    st.sampled_from(KINDS),
    st.integers(0, 2**16),
    st.sampled_from(["reflect", "valid"]),
    st.sampled_from([torch.float32, torch.float64]),
)
def test_losses_finite_with_finite_gradients_on_extremes(kind_p, kind_g, seed, border, dtype):
    pred = _extreme(kind_p, seed).to(dtype).requires_grad_(True)
    gt = _extreme(kind_g, seed + 1).to(dtype)
    s = ssim(pred, gt, border=border)
    assert torch.isfinite(s).all() and (s <= 1 + 1e-5).all() and (s >= -1 - 1e-5).all()
    p = psnr(pred, gt)
    assert torch.isfinite(p).all() and (p <= PSNR_MAX_DB).all()
    loss = (1 - s).sum() + 0.01 * (pred - gt).abs().mean() - 0.001 * p.sum()
    (grad,) = torch.autograd.grad(loss, pred)
    assert torch.isfinite(grad).all()
    if kind_p == kind_g and kind_p in ("black", "white"):
        assert torch.allclose(s.detach(), torch.ones_like(s), atol=1e-6)


def test_ssim_loss_descends():
    gt = torch.rand(1, 3, 24, 24, generator=torch.Generator().manual_seed(7))
    pred = torch.full_like(gt, 0.5).requires_grad_(True)
    opt = torch.optim.Adam([pred], lr=0.05)
    first = None
    for _ in range(30):
        loss = (1 - ssim(pred, gt)).mean()
        first = loss.item() if first is None else first
        opt.zero_grad()
        loss.backward()
        opt.step()
    assert loss.item() < 0.5 * first


# -------------------------------------------------------------------------------------- composite


def test_composite_torch_and_numpy():
    rng = np.random.default_rng(8)
    img = rng.random((2, 3, 5, 6)).astype(np.float32)
    mask = rng.random((2, 1, 5, 6)).astype(np.float32)
    color = np.array([0.2, 0.5, 1.0], dtype=np.float32)
    want = img * mask + color.reshape(1, 3, 1, 1) * (1 - mask)
    got = composite_on(torch.from_numpy(img), torch.from_numpy(mask), color.tolist())
    np.testing.assert_allclose(got.numpy(), want, rtol=1e-6)
    got = composite_on(torch.from_numpy(img), torch.from_numpy(mask[:, 0]), 1.0)  # [B, H, W] mask
    np.testing.assert_allclose(got.numpy(), img * mask + (1 - mask), rtol=1e-6)
    hwc = img[0].transpose(1, 2, 0)
    got_np = composite_on(hwc, mask[0, 0], color)
    assert got_np.dtype == np.float32
    np.testing.assert_allclose(got_np, want[0].transpose(1, 2, 0), rtol=1e-6)
    m1 = mask[0, 0][..., None]
    np.testing.assert_allclose(composite_on(hwc, m1), hwc * m1 + 1 - m1, rtol=1e-6)
    with pytest.raises(ValueError, match="color"):
        composite_on(torch.from_numpy(img), torch.from_numpy(mask), [1.0, 1.0])
    with pytest.raises(ValueError, match="mask"):
        composite_on(hwc, mask[0, 0, :3])


# ---------------------------------------------------------------------------------------- protocol


def _frame(seed: int, H: int = 40, W: int = 36):
    rng = np.random.default_rng(seed)
    gt = rng.random((H, W, 3)).astype(np.float32)
    pred = np.clip(gt + 0.1 * rng.standard_normal(gt.shape), 0, 1).astype(np.float32)
    mask = np.zeros((H, W), np.float32)
    mask[8:32, 10:26] = 1.0
    return pred, gt, mask


def test_evaluate_pair_is_the_masked_protocol():
    pred, gt, mask = _frame(9)
    out = evaluate_pair(pred, gt, mask)
    assert out["lpips"] is None and out["lpips_unmasked"] is None
    pm, gm = composite_on(pred, mask, 1.0), composite_on(gt, mask, 1.0)
    assert abs(out["psnr"] - psnr(nchw(pm), nchw(gm)).item()) < 1e-5
    assert abs(out["ssim"] - ssim(nchw(pm), nchw(gm)).item()) < 1e-6
    assert abs(out["psnr_unmasked"] - psnr(nchw(pred), nchw(gt)).item()) < 1e-5
    assert abs(out["ssim_unmasked"] - ssim(nchw(pred), nchw(gt)).item()) < 1e-6
    # changes outside the GT mask do not move the masked metrics
    pred2 = pred.copy()
    pred2[mask == 0] = 0.0
    out2 = evaluate_pair(pred2, gt, mask)
    assert out2["psnr"] == pytest.approx(out["psnr"], abs=1e-6)
    assert out2["ssim"] == pytest.approx(out["ssim"], abs=1e-6)
    assert out2["psnr_unmasked"] < out["psnr_unmasked"]
    # torch CHW input gives the same numbers
    t = evaluate_pair(torch.from_numpy(pred).permute(2, 0, 1), torch.from_numpy(gt).permute(2, 0, 1), torch.from_numpy(mask))
    for k in ("psnr", "ssim", "psnr_unmasked", "ssim_unmasked"):
        assert t[k] == pytest.approx(out[k], abs=1e-6)
    with pytest.raises(TypeError, match="pred: expected float"):
        evaluate_pair((pred * 255).astype(np.uint8), gt, mask)
    with pytest.raises(ValueError, match=r"gt_mask: expected a mask"):
        evaluate_pair(pred, gt, np.stack([mask] * 3, -1))


def test_frame_metrics_averages_frames():
    fm = FrameMetrics()
    rows = [fm.add(*_frame(s), name=f"f{s}") for s in range(3)]
    summary = fm.summary()
    assert summary["frames"] == 3 and summary["lpips"] is None
    for k in ("psnr", "ssim", "psnr_unmasked", "ssim_unmasked"):
        assert summary[k] == pytest.approx(np.mean([r[k] for r in rows]))
    fb = FrameMetrics()
    frames = [_frame(s) for s in range(3)]
    masks = torch.from_numpy(np.stack([f[2] for f in frames]))[:, None]
    fb.add_batch(nchw(*[f[0] for f in frames]), nchw(*[f[1] for f in frames]), masks)
    for k in ("psnr", "ssim"):
        assert fb.summary()[k] == pytest.approx(summary[k], abs=1e-6)
    with pytest.raises(ValueError, match="no frames"):
        FrameMetrics().summary()


def test_evaluate_batch_with_lpips_model():
    from trioman.toolkit.lpips import LPIPS

    torch.manual_seed(0)
    model = LPIPS()
    frames = [_frame(s) for s in range(2)]
    p, g = nchw(*[f[0] for f in frames]), nchw(*[f[1] for f in frames])
    m = torch.from_numpy(np.stack([f[2] for f in frames]))[:, None]
    out = evaluate_batch(p, g, m, lpips=model)
    want = model(composite_on(p, m), composite_on(g, m))
    assert torch.allclose(out["lpips"], want) and out["lpips_unmasked"].shape == (2,)
    one = evaluate_pair(*frames[0], lpips=model)
    assert one["lpips"] == pytest.approx(want[0].item(), rel=1e-5)
