"""The torch tile rasterizer against the brute-force oracle (runtime.render.reference), finite differences and gsplat."""

from __future__ import annotations

import math

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from trioman.runtime.render.reference import project_reference, rasterize_reference  # noqa: E402
from trioman.bench.scenes import extreme_scene, orbit_viewmat, random_scene  # noqa: E402
from trioman.toolkit.render import RenderOutput, project_gaussians, rasterize  # noqa: E402

TOL = 1e-5


# --------------------------------------------------------------------------------------------
# scenes


def as_tensors(scene, dtype=torch.float32):
    keys = ("means", "quats", "scales", "opacities", "colors", "viewmat", "K")
    return [torch.tensor(np.asarray(scene[k]), dtype=dtype) for k in keys]


def compare(scene, background=None, near_plane=0.01, far_plane=1e10, ref_dtype=np.float64, tol=TOL, **kw):
    """Render with the rasterizer (float32) and the oracle on the same (float32-rounded) inputs."""
    tensors = as_tensors(scene)
    arrays = [t.double().numpy() for t in tensors]
    W, H = scene["width"], scene["height"]
    bg_t = None if background is None else torch.tensor(background, dtype=torch.float32)
    out = rasterize(*tensors, W, H, background=bg_t, near_plane=near_plane, far_plane=far_plane, **kw)
    ref = rasterize_reference(*arrays, W, H, background=None if bg_t is None else bg_t.double().numpy(),
                              near_plane=near_plane, far_plane=far_plane, dtype=ref_dtype)
    rgb, alpha, depth = (np.asarray(r, dtype=np.float64) for r in ref)
    assert out.rgb.shape == (H, W, 3) and out.alpha.shape == (H, W) and out.depth.shape == (H, W)
    assert out.rgb.dtype == torch.float32
    err_rgb = np.abs(out.rgb.double().numpy() - rgb).max()
    err_alpha = np.abs(out.alpha.double().numpy() - alpha).max()
    err_depth = (np.abs(out.depth.double().numpy() - depth) / (1.0 + np.abs(depth))).max()
    assert err_rgb <= tol and err_alpha <= tol and err_depth <= tol, (err_rgb, err_alpha, err_depth)
    return out, (rgb, alpha, depth)


# --------------------------------------------------------------------------------------------
# forward vs the oracle


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("size", [(40, 32), (37, 29)])
def test_forward_matches_reference(seed, size):
    out, ref = compare(random_scene(seed, width=size[0], height=size[1]), background=[0.2, 0.5, 0.9])
    assert ref[1].max() > 0.9 and ref[1].min() < 0.1  # the scene covers part of the image


@pytest.mark.parametrize("seed", [3, 4])
def test_forward_matches_reference_posed_camera(seed):
    scene = random_scene(seed, n=80, width=48, height=36)
    scene["means"][:, 2] -= 3.5  # about the origin, which the camera looks at
    scene["viewmat"] = orbit_viewmat(0.4 * seed, 0.3, 3.5)
    compare(scene, background=[1.0, 0.0, 0.5])


@pytest.mark.parametrize("tile_size", [16, 4, 3, 1])
def test_tile_size_does_not_change_the_result(tile_size):
    scene = random_scene(5, n=80, width=45, height=38)
    out, _ = compare(scene, tile_size=tile_size)
    ref = rasterize(*as_tensors(scene), scene["width"], scene["height"])
    for a, b in zip(out, ref):
        assert torch.allclose(a, b, atol=1e-6, rtol=0)


def test_chunking_does_not_change_the_result():
    scene = random_scene(3, n=150, width=41, height=35)
    tensors = as_tensors(scene)
    W, H = scene["width"], scene["height"]
    big = rasterize(*tensors, W, H)
    tiny = rasterize(*tensors, W, H, chunk_elements=1)  # one tile per chunk, 16 Gaussians per block
    # not bitwise: float32 sums and products round at different block boundaries
    for a, b in zip(big, tiny):
        assert torch.allclose(a, b, atol=1e-6, rtol=1e-6)
    # and the gradients
    grads = []
    for ce in (1 << 18, 2048):
        ts = [t.clone().requires_grad_(i < 5) for i, t in enumerate(tensors)]
        out = rasterize(*ts, W, H, chunk_elements=ce)
        (out.rgb.sum() + out.alpha.sum() + out.depth.sum()).backward()
        grads.append([t.grad for t in ts[:5]])
    for ga, gb in zip(*grads):
        assert torch.allclose(ga, gb, atol=1e-5 * (1 + ga.abs().max()), rtol=1e-5)


def test_many_overlapping_gaussians_match_reference():
    """Long per-tile lists (several blocks carrying T) and pixels that stop."""
    scene = random_scene(11, n=400, width=34, height=26)
    scene["opacities"] = np.clip(scene["opacities"] * 1.5, 0, 1)
    compare(scene, background=[1.0, 1.0, 1.0], chunk_elements=2048)


def test_single_gaussian():
    scene = random_scene(0, n=1, width=21, height=17)
    scene["means"][0] = [0.05, -0.02, 2.0]
    scene["opacities"][0] = 0.8
    out, ref = compare(scene)
    assert 0.5 < ref[1].max() <= 0.8 + 1e-12


def test_equal_depths_are_ordered_by_index():
    n = 6
    scene = dict(means=np.array([[0.02 * i - 0.05, 0.01 * (i % 2), 2.0] for i in range(n)]),
                 quats=np.tile([1.0, 0, 0, 0], (n, 1)), scales=np.full((n, 3), 0.06), opacities=np.full(n, 0.7),
                 colors=np.random.default_rng(0).uniform(0, 1, (n, 3)), viewmat=np.eye(4),
                 K=np.array([[40.0, 0, 12.0], [0, 40.0, 10.0], [0, 0, 1]]), width=24, height=20)
    out, _ = compare(scene)
    flipped = {k: (v[::-1].copy() if k in ("means", "quats", "scales", "opacities", "colors") else v)
               for k, v in scene.items()}
    out_flipped, _ = compare(flipped)
    assert (out.rgb - out_flipped.rgb).abs().max() > 1e-3  # the order among equal depths matters


def test_n_zero_returns_background():
    bg = torch.tensor([0.1, 0.2, 0.3])
    empty = [torch.zeros(0, 3), torch.zeros(0, 4), torch.zeros(0, 3), torch.zeros(0), torch.zeros(0, 3)]
    cam = [torch.eye(4), torch.tensor([[20.0, 0, 8], [0, 20.0, 6], [0, 0, 1]])]
    out = rasterize(*empty, *cam, 16, 12, background=bg)
    assert isinstance(out, RenderOutput)
    assert torch.equal(out.rgb, bg.expand(12, 16, 3)) and not out.alpha.any() and not out.depth.any()
    out = rasterize(*empty, *cam, 16, 12)
    assert not out.rgb.any()


def test_everything_off_screen_or_culled():
    scene = random_scene(2, n=30)
    scene["means"][:10, 0] += 50.0  # far to the right
    scene["means"][10:20, 2] = -3.0  # behind the camera
    scene["opacities"][20:] = 0.0  # invisible
    ts = [t.requires_grad_(i < 5) for i, t in enumerate(as_tensors(scene))]
    bg = torch.tensor([0.3, 0.6, 0.9], requires_grad=True)
    out = rasterize(*ts, scene["width"], scene["height"], background=bg)
    assert torch.equal(out.rgb, bg.detach().expand_as(out.rgb)) and not out.alpha.any() and not out.depth.any()
    (out.rgb.sum() + out.alpha.sum()).backward()
    assert all(not t.grad.any() for t in ts[:5])
    assert torch.allclose(bg.grad, torch.full((3,), float(scene["width"] * scene["height"])))


def test_opacity_zero_and_one():
    scene = random_scene(4, n=40)
    scene["opacities"][::2] = 0.0
    scene["opacities"][1::2] = 1.0
    out, ref = compare(scene, background=[0.0, 1.0, 0.0])
    assert ref[1].max() > 0.99


def test_zero_quaternions_are_identity():
    scene = random_scene(6, n=30)
    scene["quats"][::3] = 0.0
    compare(scene)
    identity = dict(scene, quats=np.where((scene["quats"] == 0).all(1, keepdims=True), [1.0, 0, 0, 0], scene["quats"]))
    a = rasterize(*as_tensors(scene), scene["width"], scene["height"])
    b = rasterize(*as_tensors(identity), scene["width"], scene["height"])
    assert all(torch.equal(x, y) for x, y in zip(a, b))


@pytest.mark.parametrize("seed", [0, 1])
def test_extreme_scales_and_anisotropy(seed):
    out, ref = compare(extreme_scene(seed), background=[0.5, 0.5, 0.5])
    assert ref[1].min() < 0.5 < ref[1].max()  # not saturated: the small and thin ones show


def test_centres_at_and_behind_the_near_plane():
    near = 0.5  # exactly representable: float32 and float64 inputs agree on the test z >= near
    scene = random_scene(8, n=48)
    z = np.array([near, np.nextafter(np.float32(near), np.float32(0)), near + 1e-6, near - 1e-3], dtype=np.float32)
    scene["means"][:, 2] = np.tile(z, 12).astype(np.float64)
    scene["means"][:, :2] *= 0.2
    scene["scales"] = np.clip(scene["scales"], 1e-3, 0.05)
    out, ref = compare(scene, near_plane=near)
    vis = project_gaussians(*as_tensors(scene)[:4], *as_tensors(scene)[5:], scene["width"], scene["height"],
                            near_plane=near).visible
    z32 = torch.tensor(scene["means"][:, 2], dtype=torch.float32)
    assert not vis[z32 < near].any()
    assert vis[z32 >= near].any()
    compare(scene)  # default near plane 0.01: everything in front


def test_stack_of_opaque_gaussians_on_one_pixel():
    """Alpha capped at 0.99: after the first, T (1 - alpha) = 0.01f * 0.01f <= 1e-4f -> stop, excluded."""
    n, W, H = 5, 21, 17
    K = np.array([[30.0, 0.0, 10.5], [0.0, 30.0, 8.5], [0.0, 0.0, 1.0]])  # mean2d at the centre of pixel (8, 10)
    scene = dict(means=np.array([[0.0, 0.0, 2.0 + 0.1 * i] for i in range(n)]), quats=np.tile([1.0, 0, 0, 0], (n, 1)),
                 scales=np.full((n, 3), 0.02), opacities=np.ones(n), colors=np.eye(n, 3) + 0.1, viewmat=np.eye(4),
                 K=K, width=W, height=H)
    bg = [0.25, 0.5, 0.75]
    out, ref = compare(scene, background=bg)
    c0 = torch.tensor(scene["colors"][0], dtype=torch.float32)
    t_after = torch.tensor(1.0) - torch.tensor(0.99)  # float32: the first Gaussian alone
    expect = torch.tensor(0.99) * c0 + t_after * torch.tensor(bg)
    assert torch.allclose(out.rgb[8, 10], expect, atol=1e-6)
    assert abs(out.alpha[8, 10].item() - 0.99) < 1e-6
    assert abs(ref[1][8, 10] - 0.99) < 1e-6
    # the float64 render path makes the same float32 decision
    out64 = rasterize(*as_tensors(scene, torch.float64), W, H, background=torch.tensor(bg, dtype=torch.float64))
    assert abs(out64.alpha[8, 10].item() - 0.99) < 1e-6


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**31 - 1), log_scale=st.floats(-8.0, 3.0), spread=st.floats(0.0, 6.0),
       z_lo=st.floats(-2.0, 3.0), bg=st.floats(0.0, 1.0))
def test_extreme_inputs_give_finite_outputs_and_gradients(seed, log_scale, spread, z_lo, bg):
    rng = np.random.default_rng(seed)
    n, W, H = 24, 23, 19
    scene = dict(
        means=np.concatenate([rng.normal(0, 2, (n, 2)), z_lo + rng.exponential(3.0, (n, 1))], 1),
        quats=rng.normal(size=(n, 4)) * rng.integers(0, 2, (n, 1)),  # some zero quaternions
        scales=10.0 ** (log_scale + spread * rng.uniform(-1, 1, (n, 3))),
        opacities=rng.choice([0.0, 1.0, 0.5, 1 / 255, 0.004], n),
        colors=rng.uniform(0, 1, (n, 3)), viewmat=np.eye(4),
        K=np.array([[15.0, 0, 11.5], [0, 15.0, 9.5], [0, 0, 1]]), width=W, height=H)
    ts = [t.requires_grad_(i < 5) for i, t in enumerate(as_tensors(scene))]
    out = rasterize(*ts, W, H, background=torch.full((3,), bg))
    for x in out:
        assert torch.isfinite(x).all()
    assert (out.alpha >= 0).all() and (out.alpha <= 1).all()
    (out.rgb.sum() + out.alpha.sum() + 0.01 * out.depth.sum()).backward()
    for t in ts[:5]:
        assert torch.isfinite(t.grad).all()


# --------------------------------------------------------------------------------------------
# gradients


def _loss_fn(scene, dtype):
    g = torch.Generator().manual_seed(0)
    W, H = scene["width"], scene["height"]
    wr, wa, wd = (torch.rand(*shape, generator=g, dtype=torch.float64).to(dtype)
                  for shape in ((H, W, 3), (H, W), (H, W)))
    vm, K = (torch.tensor(scene[k], dtype=dtype) for k in ("viewmat", "K"))

    def loss(means, quats, scales, opacities, colors, background):
        out = rasterize(means, quats, scales, opacities, colors, vm, K, W, H, background=background)
        return (out.rgb * wr).sum() + (out.alpha * wa).sum() + 0.1 * (out.depth * wd).sum()

    return loss


def _grad_inputs(scene, dtype):
    names = ("means", "quats", "scales", "opacities", "colors")
    xs = [torch.tensor(scene[k], dtype=dtype) for k in names]
    return xs + [torch.tensor([0.3, 0.2, 0.7], dtype=dtype)]


def _fd(loss, xs, k, direction, eps=1e-6):
    plus = [x.detach().clone() for x in xs]
    minus = [x.detach().clone() for x in xs]
    plus[k] += eps * direction
    minus[k] -= eps * direction
    return (loss(*plus) - loss(*minus)) / (2 * eps)


def test_gradients_match_finite_differences_per_element():
    """Every input element of a small scene (float64 render path; no skip / stop boundary is crossed)."""
    scene = random_scene(0, n=4, width=14, height=12)
    scene["means"][:, :2] *= 0.4
    scene["opacities"] = np.array([0.3, 0.9, 0.999, 0.6])
    scene["K"][:2, 2] = [7.5, 6.5]
    scene["means"][2, :2] = 0.0  # on the centre of pixel (6, 7): alpha capped at 0.99 there, gradient 0
    loss = _loss_fn(scene, torch.float64)
    xs = [x.requires_grad_() for x in _grad_inputs(scene, torch.float64)]
    grads = torch.autograd.grad(loss(*xs), xs)
    for k, (x, g) in enumerate(zip(xs, grads)):
        num = torch.zeros_like(x)
        for i in range(x.numel()):
            e = torch.zeros_like(x)
            e.view(-1)[i] = 1.0
            num.view(-1)[i] = _fd(loss, xs, k, e)
        assert torch.allclose(g, num, atol=1e-6 * (1 + g.abs().max()), rtol=1e-5), (k, (g - num).abs().max())


@pytest.mark.parametrize("seed", [1, 2])
def test_gradients_match_finite_differences_directional(seed):
    """Random directions through every input at once, on busier scenes."""
    scene = random_scene(seed, n=25, width=24, height=20)
    scene["opacities"] = 0.05 + 0.9 * scene["opacities"]
    loss = _loss_fn(scene, torch.float64)
    xs = [x.requires_grad_() for x in _grad_inputs(scene, torch.float64)]
    grads = torch.autograd.grad(loss(*xs), xs)
    gen = torch.Generator().manual_seed(seed)
    for k, (x, g) in enumerate(zip(xs, grads)):
        for _ in range(3):
            d = torch.randn(x.shape, generator=gen, dtype=torch.float64)
            analytic = (g * d).sum()
            numeric = _fd(loss, xs, k, d)
            assert abs(analytic - numeric) <= 1e-6 * (1 + g.abs().sum()), (k, analytic.item(), numeric.item())


def test_float32_gradients_agree_with_float64():
    scene = random_scene(9, n=40, width=30, height=26)
    grads = {}
    for dt in (torch.float32, torch.float64):
        xs = [x.requires_grad_() for x in _grad_inputs(scene, dt)]
        grads[dt] = torch.autograd.grad(_loss_fn(scene, dt)(*xs), xs)
    for g32, g64 in zip(grads[torch.float32], grads[torch.float64]):
        assert torch.allclose(g32.double(), g64, atol=2e-4 * (1 + g64.abs().max()), rtol=1e-3)


# --------------------------------------------------------------------------------------------
# projection


def test_projection_matches_reference():
    scene = random_scene(12, n=50)
    scene["means"][:5, 2] = -1.0  # behind
    scene["quats"][5:8] = 0.0
    ts = as_tensors(scene, torch.float64)
    proj = project_gaussians(*ts[:4], *ts[5:], scene["width"], scene["height"])
    ref = project_reference(*(t.numpy() for t in ts[:4]), *(t.numpy() for t in ts[5:]), scene["width"], scene["height"])
    for i, r in enumerate(ref):
        assert bool(proj.visible[i]) == (r is not None)
        if r is None:
            assert proj.radii[i].tolist() == [0, 0]
            continue
        assert np.allclose(proj.means2d[i].numpy(), r["mean2d"], atol=1e-9)
        assert np.allclose(proj.conics[i].numpy(), r["conic"], rtol=1e-9, atol=1e-12)
        assert proj.radii[i].tolist() == [int(r["radii"][0]), int(r["radii"][1])]
        assert abs(proj.depths[i].item() - r["depth"]) < 1e-12


@pytest.mark.parametrize("seed", [13, 14])
def test_isotropic_projection_matches_reference_and_the_general_path(seed):
    """One scale per Gaussian broadcast to three axes (the avatar's expand) takes the isotropic path (no
    quaternion read): the oracle's conics, and the general path's values and gradients (the general path runs
    when the quaternions need a gradient)."""
    from trioman.toolkit.render.projection import project

    scene = random_scene(seed, n=60)
    scene["scales"][:] = scene["scales"][:, :1]
    scene["scales"][:4] *= np.array([1e-4, 1e-2, 10.0, 100.0])[:, None]  # tiny to huge, each still isotropic
    scene["means"][4, :2] = 50.0  # far off the axis: the tan-fov clamp applies
    ts = as_tensors(scene, torch.float64)
    W, H = scene["width"], scene["height"]
    proj = project_gaussians(ts[0], ts[1], ts[2][:, :1].expand(-1, 3), ts[3], *ts[5:], W, H)
    ref = project_reference(*(t.numpy() for t in ts[:4]), *(t.numpy() for t in ts[5:]), W, H)
    assert sum(r is not None for r in ref) > 30
    for i, r in enumerate(ref):
        assert bool(proj.visible[i]) == (r is not None)
        if r is not None:
            assert np.allclose(proj.conics[i].numpy(), r["conic"], rtol=1e-9, atol=1e-12)
            assert proj.radii[i].tolist() == [int(r["radii"][0]), int(r["radii"][1])]
    results = []
    for general in (False, True):
        means, scales = ts[0].clone().requires_grad_(), ts[2][:, :1].clone().requires_grad_()
        quats = ts[1].clone().requires_grad_(general)
        p = project(means, quats, scales.expand(-1, 3), ts[3], *ts[5:], W, H)
        out = torch.cat([p.means2d, p.chol, p.conics], 1)
        weights = torch.randn(out.shape, generator=torch.Generator().manual_seed(seed), dtype=torch.float64)
        grads = torch.autograd.grad((out * weights).sum(), (means, scales))
        results.append((p.ids, out.detach(), grads))
    (ids_i, out_i, grads_i), (ids_g, out_g, grads_g) = results
    assert torch.equal(ids_i, ids_g)
    torch.testing.assert_close(out_i, out_g, rtol=1e-9, atol=1e-12)
    for a, b in zip(grads_i, grads_g):
        torch.testing.assert_close(a, b, rtol=1e-8, atol=1e-10 * float(b.abs().max()))


def test_projection_matches_gsplat_torch_reference():
    impl = pytest.importorskip("gsplat.cuda._torch_impl")
    scene = random_scene(13, n=200, width=64, height=48)
    scene["viewmat"] = orbit_viewmat(0.3, 0.2, 4.0)
    scene["means"][:, 2] -= 3.5  # around the origin the camera looks at
    scene["means"][:20, :2] *= 8.0  # some off screen, exercising the tan-fov clamp
    m, q, s, o, _, vm, K = as_tensors(scene, torch.float64)
    W, H = scene["width"], scene["height"]
    covars, _ = impl._quat_scale_to_covar_preci(q, s, compute_preci=False)
    radii_g, means2d_g, depths_g, conics_g, _ = impl._fully_fused_projection(m, covars, vm[None], K[None], W, H,
                                                                             eps2d=0.3)
    radii_g, means2d_g, depths_g, conics_g = radii_g[0], means2d_g[0], depths_g[0], conics_g[0]
    # gsplat's torch reference uses a fixed 3.33-sigma extent: opacities=None selects the same rule
    proj = project_gaussians(m, q, s, None, vm, K, W, H)
    vis = proj.visible
    assert vis.sum() > 100 and torch.equal(vis, (radii_g > 0).all(-1))
    assert torch.equal(proj.radii[vis], radii_g[vis].int())
    scale = means2d_g[vis].abs().max()
    assert torch.allclose(proj.means2d[vis], means2d_g[vis], atol=1e-4 * scale, rtol=0)
    assert torch.allclose(proj.depths, depths_g, atol=1e-12)
    assert torch.allclose(proj.conics[vis], conics_g[vis], atol=1e-4 * conics_g[vis].abs().max(), rtol=1e-6)
    # opacity-aware extent: r = ceil(sqrt(2 ln(255 o)) sqrt(Sigma2d_ii)), the 3.33 cap never binds for o <= 1
    assert math.sqrt(2 * math.log(255)) < 3.33
    o = torch.rand(len(o), generator=torch.Generator().manual_seed(0), dtype=torch.float64) * 0.9 + 0.1
    proj_o = project_gaussians(m, q, s, o, vm, K, W, H)
    A, B, C = conics_g.unbind(-1)
    det = A * C - B * B
    cov_diag = torch.stack([C / det, A / det], -1)  # diagonal of the inverse conic
    expect = torch.ceil(torch.sqrt(2 * torch.log(255 * o))[:, None] * torch.sqrt(cov_diag))
    both = proj_o.visible & vis
    assert both.sum() > 100
    close = (expect[both] - proj_o.radii[both]).abs()
    assert (close <= 1).all() and (close == 0).float().mean() > 0.99


# --------------------------------------------------------------------------------------------
# input validation


def _valid_args():
    scene = random_scene(0, n=7, width=16, height=12)
    return as_tensors(scene) + [16, 12]


@pytest.mark.parametrize("index,name", [(0, "means"), (1, "quats"), (2, "scales"), (3, "opacities"), (4, "colors"),
                                        (5, "viewmat"), (6, "K")])
@pytest.mark.parametrize("bad", [float("nan"), float("inf")])
def test_nan_or_inf_is_rejected_with_the_field_name(index, name, bad):
    args = _valid_args()
    args[index] = args[index].clone()
    args[index].view(-1)[1] = bad
    with pytest.raises(ValueError, match=rf"^{name}: 1 of {args[index].numel()} values are NaN or Inf"):
        rasterize(*args)


def test_background_nan_is_rejected():
    with pytest.raises(ValueError, match=r"^background: 1 of 3 values are NaN or Inf"):
        rasterize(*_valid_args(), background=torch.tensor([0.0, float("nan"), 0.0]))


@pytest.mark.parametrize("index,name,shape", [(0, "means", (7, 2)), (1, "quats", (7, 3)), (2, "scales", (6, 3)),
                                              (3, "opacities", (7, 1)), (4, "colors", (7, 4)), (5, "viewmat", (3, 4)),
                                              (6, "K", (3, 3, 1))])
def test_wrong_shapes_are_rejected(index, name, shape):
    args = _valid_args()
    args[index] = torch.zeros(shape)
    with pytest.raises(ValueError, match=rf"^{name}: expected shape"):
        rasterize(*args)


@pytest.mark.parametrize("index,name,value",
                         [(7, "width", 0), (8, "height", -3), (7, "width", 2.5), (8, "height", True)])
def test_bad_image_size_is_rejected(index, name, value):
    args = _valid_args()
    args[index] = value
    with pytest.raises(ValueError, match=rf"^{name}: must be a positive int, got"):
        rasterize(*args)


def test_out_of_range_values_are_rejected():
    args = _valid_args()
    args[3] = args[3].clone()
    args[3][:2] = 1.5
    with pytest.raises(ValueError, match=r"^opacities: 2 of 7 values lie outside \[0, 1\]"):
        rasterize(*args)
    args = _valid_args()
    args[2] = -args[2]
    with pytest.raises(ValueError, match=r"^scales: 21 of 21 values are negative"):
        rasterize(*args)
    with pytest.raises(ValueError, match=r"^near_plane"):
        rasterize(*_valid_args(), near_plane=0.0)
    with pytest.raises(ValueError, match=r"^far_plane"):
        rasterize(*_valid_args(), near_plane=2.0, far_plane=1.0)
    with pytest.raises(ValueError, match=r"^chunk_elements"):
        rasterize(*_valid_args(), chunk_elements=0)
    with pytest.raises(ValueError, match=r"^tile_size"):
        rasterize(*_valid_args(), tile_size=0)
