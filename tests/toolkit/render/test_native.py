"""The C rasterizer kernel (backend="native") against the torch path (backend="torch"), and its loader."""

from __future__ import annotations

import os
import shutil
import tomllib
import warnings
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from trioman.bench.scenes import random_scene  # noqa: E402
from trioman.toolkit.render import native, rasterize  # noqa: E402

IMAGE_TOL = 1e-5
GRAD_TOL = 1e-5  # times 1 + max |grad| of the input
NAMES = ("means", "quats", "scales", "opacities", "colors", "background")


@pytest.fixture(scope="module")
def kernel():
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        lib = native.load()
    if lib is None and os.environ.get(native.ENV_SWITCH) == "0":
        pytest.skip(f"the C kernel is switched off ({native.ENV_SWITCH}=0)")
    if lib is None:
        reasons = [str(w.message) for w in caught]
        # a machine with a C compiler must build it (a broken kernel may not hide as a skip); others fall back
        assert shutil.which(native.compiler_command(Path("x"))[0]) is None, f"the C kernel failed to build: {reasons}"
        pytest.skip(f"the C kernel cannot be built here (no C compiler): {reasons}")
    return lib


@pytest.fixture
def threads():
    previous = torch.get_num_threads()
    yield torch.set_num_threads
    torch.set_num_threads(previous)


def dense(seed):
    """Many overlapping Gaussians: long lists, several pixels stop."""
    scene = random_scene(seed, n=400, width=37, height=23)
    scene["opacities"] = np.clip(scene["opacities"] * 1.5, 0, 1)
    return scene


def opaque(seed):
    """Opaque Gaussians: most pixels reach the stop rule (T (1 - alpha) <= 1e-4)."""
    scene = random_scene(seed, n=150, width=37, height=23)
    scene["opacities"] = np.where(np.arange(150) % 3 == 0, 1.0, 0.995)
    scene["scales"] = np.clip(scene["scales"] * 2, 0.05, 0.5)
    return scene


def off_screen(seed):
    """Gaussians spread beyond the image: boxes cut by its edges."""
    scene = random_scene(seed, n=200, width=37, height=23)
    scene["means"][:, :2] *= 2.5
    return scene


def stack(_seed):
    """Five opaque Gaussians centred on one pixel: alpha capped at 0.99, then the stop at T = 0.01^2."""
    n = 5
    K = np.array([[30.0, 0.0, 10.5], [0.0, 30.0, 8.5], [0.0, 0.0, 1.0]])
    return dict(means=np.array([[0.0, 0.0, 2.0 + 0.1 * i] for i in range(n)]), quats=np.tile([1.0, 0, 0, 0], (n, 1)),
                scales=np.full((n, 3), 0.02), opacities=np.ones(n), colors=np.eye(n, 3) + 0.1, viewmat=np.eye(4),
                K=K, width=21, height=17)


def render(scene, backend, **kw):
    """-> (rgb, alpha, depth), the gradients of a weighted sum of them w.r.t. NAMES."""
    keys = ("means", "quats", "scales", "opacities", "colors", "viewmat", "K")
    ts = [torch.tensor(np.asarray(scene[k]), dtype=torch.float32) for k in keys]
    for t in ts[:5]:
        t.requires_grad_()
    bg = torch.tensor([0.3, 0.2, 0.7], requires_grad=True)
    out = rasterize(*ts, scene["width"], scene["height"], background=bg, backend=backend, **kw)
    gen = torch.Generator().manual_seed(0)
    loss = sum((x * torch.rand(x.shape, generator=gen)).sum() for x in out)
    loss.backward()
    return [x.detach() for x in out], [t.grad for t in ts[:5]] + [bg.grad]


def assert_backends_agree(scene, **kw):
    (img_t, grad_t), (img_n, grad_n) = render(scene, "torch", **kw), render(scene, "native", **kw)
    for name, a, b in zip(("rgb", "alpha", "depth"), img_t, img_n):
        err = float((a - b).abs().max())
        assert err <= IMAGE_TOL, (name, err)
    for name, a, b in zip(NAMES, grad_t, grad_n):
        err = float((a - b).abs().max())
        assert err <= GRAD_TOL * (1 + float(a.abs().max())), (name, err, float(a.abs().max()))
    return img_n


@pytest.mark.parametrize("n_threads", [1, 2])
@pytest.mark.parametrize("tile_size", [1, 3, 4, 8, 16])
@pytest.mark.parametrize("make", [dense, opaque, off_screen], ids=lambda f: f.__name__)
def test_native_matches_torch(kernel, threads, make, tile_size, n_threads):
    threads(n_threads)
    for seed in (0, 1):
        assert_backends_agree(make(seed), tile_size=tile_size)


def test_the_opaque_scene_nears_the_stop_rule(kernel):
    _, alpha, _ = render(opaque(0), "native")[0]
    assert float((alpha > 0.999).float().mean()) > 0.2  # T < 1e-3: within a factor 10 of the stop


@pytest.mark.parametrize("tile_size", [None, 1, 4])
def test_opaque_stack_stops_after_the_first(kernel, tile_size):
    rgb, alpha, _ = assert_backends_agree(stack(0), tile_size=tile_size)
    assert abs(float(alpha[8, 10]) - 0.99) < 1e-6


def test_default_tile_size_and_more_threads(kernel, threads):
    threads(2)
    assert_backends_agree(dense(2))
    assert_backends_agree(off_screen(3), chunk_elements=2048)


def test_auto_uses_the_kernel_for_float32_cpu(kernel, monkeypatch):
    scene = dense(4)
    calls = []
    load = native.load
    monkeypatch.setattr(native, "load", lambda: calls.append(1) or load())
    img_auto, _ = render(scene, "auto")
    img_native, _ = render(scene, "native")
    assert calls and all(torch.equal(a, b) for a, b in zip(img_auto, img_native))


def test_switched_off_auto_uses_torch_and_native_raises(monkeypatch):
    monkeypatch.setenv(native.ENV_SWITCH, "0")
    assert native.load() is None
    scene = dense(5)
    img_auto, grad_auto = render(scene, "auto")
    img_torch, grad_torch = render(scene, "torch")
    assert all(torch.equal(a, b) for a, b in zip(img_auto + grad_auto, img_torch + grad_torch))
    with pytest.raises(RuntimeError, match="TRIOMAN_NATIVE=0"):
        render(scene, "native")


def test_broken_compiler_warns_once_and_falls_back(monkeypatch, tmp_path):
    monkeypatch.setenv("CC", "/nonexistent/trioman-cc")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    monkeypatch.setattr(native, "_loaded", {})
    scene = dense(6)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        img_auto, _ = render(scene, "auto")
        render(scene, "auto")
    assert len(caught) == 1 and "/nonexistent/trioman-cc" in str(caught[0].message)
    img_torch, _ = render(scene, "torch")
    assert all(torch.equal(a, b) for a, b in zip(img_auto, img_torch))
    with pytest.raises(RuntimeError, match="could not be built"):
        render(scene, "native")
    assert list(tmp_path.rglob("*.so")) == []  # no half-written library left


def test_build_renames_the_finished_library_into_the_cache(kernel, monkeypatch, tmp_path):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    monkeypatch.setattr(native, "_loaded", {})
    assert native.load() is not None
    built = list((tmp_path / "trioman" / "kernels").iterdir())
    assert len(built) == 1 and built[0].suffix == ".so" and len(built[0].stem) == 64  # <sha256>.so, no temporary


def test_float64_native_and_unknown_backends_are_rejected():
    scene = random_scene(0, n=7, width=16, height=12)
    ts = [torch.tensor(np.asarray(scene[k]), dtype=torch.float64)
          for k in ("means", "quats", "scales", "opacities", "colors", "viewmat", "K")]
    with pytest.raises(ValueError, match="^backend: 'native' renders float32"):
        rasterize(*ts, 16, 12, backend="native")
    with pytest.raises(ValueError, match="^backend: must be one of"):
        rasterize(*ts, 16, 12, backend="cuda")
    rasterize(*ts, 16, 12, backend="auto")  # float64 stays on the torch path


def test_the_source_is_package_data():
    root = Path(__file__).resolve().parents[3]
    setup = tomllib.loads((root / "pyproject.toml").read_text())["tool"]["setuptools"]
    assert native.SOURCE.name in setup["package-data"]["trioman.toolkit.render"]
    assert native.SOURCE.exists()
