"""The numpy splat renderer against the brute-force oracle (trioman.runtime.render.reference)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tests.conftest import run_python
from trioman.bench.scenes import extreme_scene, orbit_viewmat, random_scene
from trioman.runtime.render import RenderOutput, rasterize
from trioman.runtime.render.reference import rasterize_reference

TOL = 1e-5
KEYS = ("means", "quats", "scales", "opacities", "colors", "viewmat", "K")


def as_arrays(scene) -> list[np.ndarray]:
    """The scene's inputs rounded to float32 (what the renderer and the oracle both see)."""
    return [np.asarray(scene[k], dtype=np.float32) for k in KEYS]


def render(scene, background=None, **kw) -> RenderOutput:
    bg = None if background is None else np.asarray(background, dtype=np.float32)
    return rasterize(*as_arrays(scene), scene["width"], scene["height"], background=bg, **kw)


def compare(scene, background=None, near_plane=0.01, far_plane=1e10, tol=TOL, **kw):
    """Render with the numpy renderer and the oracle (float64 of the same float32 inputs)."""
    W, H = scene["width"], scene["height"]
    bg = None if background is None else np.asarray(background, dtype=np.float32)
    out = render(scene, bg, near_plane=near_plane, far_plane=far_plane, **kw)
    ref = rasterize_reference(*(a.astype(np.float64) for a in as_arrays(scene)), W, H,
                              background=None if bg is None else bg.astype(np.float64),
                              near_plane=near_plane, far_plane=far_plane)
    assert isinstance(out, RenderOutput)
    assert out.rgb.shape == (H, W, 3) and out.alpha.shape == (H, W) and out.depth.shape == (H, W)
    assert all(x.dtype == np.float32 for x in out)
    err_rgb = np.abs(out.rgb - ref[0]).max()
    err_alpha = np.abs(out.alpha - ref[1]).max()
    err_depth = (np.abs(out.depth - ref[2]) / (1.0 + np.abs(ref[2]))).max()
    assert err_rgb <= tol and err_alpha <= tol and err_depth <= tol, (err_rgb, err_alpha, err_depth)
    return out, ref


# --------------------------------------------------------------------------------------------
# against the oracle


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("size", [(40, 32), (37, 29)])
def test_matches_reference(seed, size):
    out, ref = compare(random_scene(seed, width=size[0], height=size[1]), background=[0.2, 0.5, 0.9])
    assert ref[1].max() > 0.9 and ref[1].min() < 0.1  # the scene covers part of the image


@pytest.mark.parametrize("seed", [3, 4])
def test_matches_reference_posed_camera(seed):
    scene = random_scene(seed, n=80, width=48, height=36)
    scene["means"][:, 2] -= 3.5  # about the origin, which the camera looks at
    scene["viewmat"] = orbit_viewmat(0.4 * seed, 0.3, 3.5)
    compare(scene, background=[1.0, 0.0, 0.5])


@pytest.mark.parametrize("tile_size", [1, 3, 4, 8, 16, 64])
def test_tile_size_does_not_change_the_result(tile_size):
    scene = random_scene(5, n=80, width=45, height=38)
    out, _ = compare(scene, tile_size=tile_size)
    for a, b in zip(out, render(scene)):
        assert np.allclose(a, b, atol=2e-6, rtol=2e-6)


def test_3sigma_extent_cuts_only_faint_tails():
    """gsplat's fixed 3-sigma box loses at most the alpha beyond it, o exp(-4.5) < 0.012 per Gaussian,
    and loses something on opaque scenes; the default opacity rule matches the oracle (above)."""
    scene = random_scene(5, n=80, width=45, height=38)
    scene["opacities"][:] = 1.0
    exact, _ = compare(scene)
    cut = render(scene, extent="3sigma")
    diff = np.abs(cut.alpha - exact.alpha)
    assert 1e-4 < diff.max() < 0.05 and np.isfinite(cut.rgb).all()
    assert (cut.alpha <= exact.alpha + 1e-6).all()  # only tails are removed


def test_unknown_extent_rule_is_rejected():
    with pytest.raises(ValueError, match="extent"):
        render(random_scene(0), extent="4sigma")


def test_chunking_does_not_change_the_result():
    scene = random_scene(3, n=150, width=41, height=35)
    tiny, _ = compare(scene, chunk_elements=1)  # one tile per chunk, the shortest blocks
    for a, b in zip(render(scene), tiny):
        assert np.allclose(a, b, atol=2e-6, rtol=2e-6)


def test_many_overlapping_gaussians_match_reference():
    """Long per-tile lists (several blocks carrying T) and pixels that stop."""
    scene = random_scene(11, n=400, width=34, height=26)
    scene["opacities"] = np.clip(scene["opacities"] * 1.5, 0, 1)
    for tile_size in (4, 16):
        compare(scene, background=[1.0, 1.0, 1.0], chunk_elements=2048, tile_size=tile_size)


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
    flipped = {k: (v[::-1].copy() if k in KEYS[:5] else v) for k, v in scene.items()}
    out_flipped, _ = compare(flipped)
    assert np.abs(out.rgb - out_flipped.rgb).max() > 1e-3  # the order among equal depths matters


def test_n_zero_returns_background():
    empty = [np.zeros((0, 3)), np.zeros((0, 4)), np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3))]
    cam = [np.eye(4), np.array([[20.0, 0, 8], [0, 20.0, 6], [0, 0, 1]])]
    out = rasterize(*empty, *cam, 16, 12, background=np.array([0.1, 0.2, 0.3]))
    assert np.array_equal(out.rgb, np.broadcast_to(np.float32([0.1, 0.2, 0.3]), (12, 16, 3)))
    assert not out.alpha.any() and not out.depth.any() and all(x.dtype == np.float32 for x in out)
    assert not rasterize(*empty, *cam, 16, 12).rgb.any()  # background None: black


def test_everything_off_screen_or_culled():
    scene = random_scene(2, n=30)
    scene["means"][:10, 0] += 50.0  # far to the right
    scene["means"][10:20, 2] = -3.0  # behind the camera
    scene["opacities"][20:] = 0.0  # invisible
    out, _ = compare(scene, background=[0.3, 0.6, 0.9])
    assert np.array_equal(out.rgb, np.broadcast_to(np.float32([0.3, 0.6, 0.9]), out.rgb.shape))
    assert not out.alpha.any() and not out.depth.any()


def test_culled_extras_do_not_change_the_result():
    """Gaussians behind the camera, beyond far, transparent or off screen leave the image bit for bit."""
    scene = random_scene(7, n=50)
    rng = np.random.default_rng(0)
    n = 500
    extra = dict(means=np.concatenate([rng.uniform([-1, -1, -5], [1, 1, -0.5], (n // 2, 3)),  # behind
                                       rng.uniform([30, -1, 2], [60, 1, 5], (n // 2, 3))]),  # far right
                 quats=rng.normal(size=(n, 4)), scales=rng.uniform(0.01, 0.3, (n, 3)), opacities=rng.uniform(0, 1, n),
                 colors=rng.uniform(0, 1, (n, 3)))
    more = dict(scene, **{k: np.concatenate([scene[k], v]) for k, v in extra.items()})
    for a, b in zip(render(scene), render(more)):
        assert np.array_equal(a, b)


def test_large_gaussians_with_centres_off_screen_reach_in():
    """The cheap screen-bound cull is conservative: big Gaussians centred outside the image still show."""
    scene = random_scene(9, n=12)
    scene["means"][:, 0] = np.linspace(-4.0, -2.0, 12)  # left of the view (x / z < -0.5 at z <= 5)
    scene["scales"][:] = np.linspace(0.3, 1.5, 12)[:, None] * [1.0, 0.2, 0.5]
    scene["opacities"][:] = 0.9
    out, ref = compare(scene)
    assert ref[1].max() > 0.05


def test_opacity_zero_and_one():
    scene = random_scene(4, n=40)
    scene["opacities"][::2] = 0.0
    scene["opacities"][1::2] = 1.0
    out, ref = compare(scene, background=[0.0, 1.0, 0.0])
    assert ref[1].max() > 0.99



@pytest.mark.parametrize("chunk_elements", [1, 2048, 1 << 16])
def test_all_opaque_and_mixed_opacity_blocks(chunk_elements):
    # all opacities 1 (log o = 0: the evaluation skips the log-opacity row broadcast) next to blocks
    # that mix opacity 1 with others and with the padding pair; every chunking gives the reference
    scene = random_scene(6, n=120, width=43, height=37)
    scene["opacities"][:] = 1.0
    compare(scene, background=[0.3, 0.0, 1.0], chunk_elements=chunk_elements)
    scene["opacities"][::3] = 0.6
    compare(scene, background=[0.3, 0.0, 1.0], chunk_elements=chunk_elements)

def test_zero_quaternions_are_identity():
    scene = random_scene(6, n=30)
    scene["quats"][::3] = 0.0
    compare(scene)
    identity = dict(scene, quats=np.where((scene["quats"] == 0).all(1, keepdims=True), [1.0, 0, 0, 0], scene["quats"]))
    for a, b in zip(render(scene), render(identity)):
        assert np.array_equal(a, b)


@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.parametrize("tile_size", [4, 16])
def test_extreme_scales_and_anisotropy(seed, tile_size):
    out, ref = compare(extreme_scene(seed), background=[0.5, 0.5, 0.5], tile_size=tile_size)
    assert ref[1].min() < 0.5 < ref[1].max()  # not saturated: the small and thin ones show


def test_centres_at_and_behind_the_near_plane():
    near = 0.5  # exactly representable: float32 and float64 inputs agree on the test z >= near
    scene = random_scene(8, n=48)
    z = np.array([near, np.nextafter(np.float32(near), np.float32(0)), near + 1e-6, near - 1e-3], dtype=np.float32)
    scene["means"][:, 2] = np.tile(z, 12).astype(np.float64)
    scene["means"][:, :2] *= 0.2
    scene["scales"] = np.clip(scene["scales"], 1e-3, 0.05)
    out, ref = compare(scene, near_plane=near)
    assert ref[1].max() > 0.5
    compare(scene)  # default near plane 0.01: everything in front


def test_stack_of_opaque_gaussians_on_one_pixel():
    """Alpha capped at 0.99: after the first, T (1 - alpha) = 0.01f * 0.01f <= 1e-4f -> stop, excluded."""
    n, W, H = 5, 21, 17
    K = np.array([[30.0, 0.0, 10.5], [0.0, 30.0, 8.5], [0.0, 0.0, 1.0]])  # mean2d at the centre of pixel (8, 10)
    scene = dict(means=np.array([[0.0, 0.0, 2.0 + 0.1 * i] for i in range(n)]), quats=np.tile([1.0, 0, 0, 0], (n, 1)),
                 scales=np.full((n, 3), 0.02), opacities=np.ones(n), colors=np.eye(n, 3) + 0.1, viewmat=np.eye(4),
                 K=K, width=W, height=H)
    bg = np.float32([0.25, 0.5, 0.75])
    for tile_size in (1, 4, 16):
        out, ref = compare(scene, background=bg, tile_size=tile_size)
        t_after = np.float32(1.0) - np.float32(0.99)  # float32: the first Gaussian alone
        expect = np.float32(0.99) * scene["colors"][0].astype(np.float32) + t_after * bg
        assert np.allclose(out.rgb[8, 10], expect, atol=1e-6)
        assert abs(out.alpha[8, 10] - 0.99) < 1e-6 and abs(ref[1][8, 10] - 0.99) < 1e-6


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**31 - 1), log_scale=st.floats(-8.0, 3.0), spread=st.floats(0.0, 6.0),
       z_lo=st.floats(-2.0, 3.0), bg=st.floats(0.0, 1.0), tile_size=st.sampled_from([1, 4, 16]))
def test_extreme_inputs_give_finite_outputs(seed, log_scale, spread, z_lo, bg, tile_size):
    rng = np.random.default_rng(seed)
    n, W, H = 24, 23, 19
    scene = dict(
        means=np.concatenate([rng.normal(0, 2, (n, 2)), z_lo + rng.exponential(3.0, (n, 1))], 1),
        quats=rng.normal(size=(n, 4)) * rng.integers(0, 2, (n, 1)),  # some zero quaternions
        scales=10.0 ** (log_scale + spread * rng.uniform(-1, 1, (n, 3))),
        opacities=rng.choice([0.0, 1.0, 0.5, 1 / 255, 0.004], n),
        colors=rng.uniform(0, 1, (n, 3)), viewmat=np.eye(4),
        K=np.array([[15.0, 0, 11.5], [0, 15.0, 9.5], [0, 0, 1]]), width=W, height=H)
    out = render(scene, np.full(3, bg), tile_size=tile_size)
    for x in out:
        assert np.isfinite(x).all()
    assert (out.alpha >= 0).all() and (out.alpha <= 1).all()


# --------------------------------------------------------------------------------------------
# input validation


def _valid_args() -> list:
    return as_arrays(random_scene(0, n=7, width=16, height=12)) + [16, 12]


@pytest.mark.parametrize("index,name", list(enumerate(KEYS)))
@pytest.mark.parametrize("bad", [float("nan"), float("inf")])
def test_nan_or_inf_is_rejected_with_the_field_name(index, name, bad):
    args = _valid_args()
    args[index] = args[index].copy()
    args[index].reshape(-1)[1] = bad
    with pytest.raises(ValueError, match=rf"^{name}: 1 of {args[index].size} values are NaN or Inf"):
        rasterize(*args)


def test_background_nan_is_rejected():
    with pytest.raises(ValueError, match=r"^background: 1 of 3 values are NaN or Inf"):
        rasterize(*_valid_args(), background=np.array([0.0, np.nan, 0.0]))
    with pytest.raises(ValueError, match=r"^background: expected shape \[3\], got \[4\]"):
        rasterize(*_valid_args(), background=np.zeros(4))


@pytest.mark.parametrize("index,name,shape", [(0, "means", (7, 2)), (1, "quats", (7, 3)), (2, "scales", (6, 3)),
                                              (3, "opacities", (7, 1)), (4, "colors", (7, 4)), (5, "viewmat", (3, 4)),
                                              (6, "K", (3, 3, 1))])
def test_wrong_shapes_are_rejected(index, name, shape):
    args = _valid_args()
    args[index] = np.zeros(shape)
    with pytest.raises(ValueError, match=rf"^{name}: expected shape"):
        rasterize(*args)


def test_non_numeric_arrays_are_rejected():
    args = _valid_args()
    args[4] = np.full((7, 3), "red")
    with pytest.raises(ValueError, match=r"^colors: expected a real-valued array"):
        rasterize(*args)


@pytest.mark.parametrize("index,name,value", [(7, "width", 0), (8, "height", -3), (7, "width", 2.5), (8, "height", True)])
def test_bad_image_size_is_rejected(index, name, value):
    args = _valid_args()
    args[index] = value
    with pytest.raises(ValueError, match=rf"^{name}: must be a positive int, got"):
        rasterize(*args)


def test_out_of_range_values_are_rejected():
    args = _valid_args()
    args[3] = args[3].copy()
    args[3][:2] = 1.5
    with pytest.raises(ValueError, match=r"^opacities: 2 of 7 values lie outside \[0, 1\]"):
        rasterize(*args)
    args = _valid_args()
    args[2] = -args[2]
    with pytest.raises(ValueError, match=r"^scales: 21 of 21 values are negative"):
        rasterize(*args)
    args = _valid_args()
    args[6] = args[6].copy()
    args[6][1, 1] = 0.0
    with pytest.raises(ValueError, match=r"^K: focal lengths must be > 0"):
        rasterize(*args)
    with pytest.raises(ValueError, match=r"^near_plane"):
        rasterize(*_valid_args(), near_plane=0.0)
    with pytest.raises(ValueError, match=r"^far_plane"):
        rasterize(*_valid_args(), near_plane=2.0, far_plane=1.0)
    with pytest.raises(ValueError, match=r"^tile_size"):
        rasterize(*_valid_args(), tile_size=0)
    with pytest.raises(ValueError, match=r"^chunk_elements"):
        rasterize(*_valid_args(), chunk_elements=0)


# --------------------------------------------------------------------------------------------
# runtime: no torch


def test_renders_where_torch_cannot_be_imported():
    proc = run_python("""
        import sys
        import numpy as np
        from trioman.runtime.render import rasterize
        n = 20
        rng = np.random.default_rng(0)
        out = rasterize(rng.uniform([-1, -1, 2], [1, 1, 4], (n, 3)), rng.normal(size=(n, 4)),
                        np.full((n, 3), 0.1), np.full(n, 0.8), rng.uniform(0, 1, (n, 3)), np.eye(4),
                        np.array([[20.0, 0, 16], [0, 20.0, 12], [0, 0, 1]]), 32, 24)
        assert out.alpha.max() > 0.5
        assert "torch" not in sys.modules or sys.modules["torch"] is None
        print("ok")
    """, block_torch=True)
    assert proc.returncode == 0 and proc.stdout.strip() == "ok", proc.stderr


@pytest.mark.parametrize("seed", range(6))
def test_float32_prefilter_keeps_every_gaussian_the_exact_tests_keep(seed):
    """The cheap cull may keep extra Gaussians, never drop one the float64 projection keeps: centres
    straddling the near/far planes and the image borders, scales from 1e-6 to 1e2 m."""
    from trioman.runtime.cameras import look_at
    from trioman.runtime.render.projection import _prefilter, project

    rng = np.random.default_rng(seed)
    n = 4000
    W, H = 64, 48
    K = np.array([[50.0, 0, 32], [0, 50.0, 24], [0, 0, 1]])
    vm = look_at(rng.normal(size=3) * 3, np.zeros(3))
    z = np.concatenate([rng.uniform(-0.1, 0.1, n // 4), 0.01 + rng.normal(0, 1e-4, n // 4), rng.uniform(0.01, 30, n // 2)])
    ang = rng.uniform(-1.5, 1.5, (n, 2)) * np.array([W / 2 / K[0, 0], H / 2 / K[1, 1]])
    cam = np.concatenate([ang * np.abs(z)[:, None], z[:, None]], 1)
    means = ((cam - vm[:3, 3]) @ vm[:3, :3]).astype(np.float32)
    scales = (10.0 ** rng.uniform(-6, 2, (n, 1)) * rng.uniform(0.2, 1, (n, 3))).astype(np.float32)
    quats = rng.normal(size=(n, 4)).astype(np.float32)
    opac = rng.uniform(0, 1, n).astype(np.float32)
    for far in (1e10, 5.0):
        kept = set(_prefilter(means, scales, opac, vm[:3, :3], vm[:3, 3], K, W, H, 0.01, far).tolist())
        exact = project(means, quats, scales, opac, vm, K, W, H, 0.01, far)
        assert set(exact.ids.tolist()) <= kept
        assert len(kept) < n  # it does cull
