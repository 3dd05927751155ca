"""LPIPS-AlexNet: weight files in the torchvision / lpips key layouts, the forward pass against a
hand-written torch.nn.functional reference, clear errors, and the TRIOMAN_LPIPS_DIR lookup.

No real weights exist on the test machines: random weights are saved in the real files' layouts.
"""

import fractions

import pytest

torch = pytest.importorskip("torch")
import torch.nn.functional as F  # noqa: E402

from trioman.toolkit.lpips import (  # noqa: E402
    ENV_VAR,
    LPIPS,
    NOT_FOUND_MESSAGE,
    find_lpips_weights,
    load_lpips,
    load_lpips_state_dict,
)

CONVS = {0: (64, 3, 11), 3: (192, 64, 5), 6: (384, 192, 3), 8: (256, 384, 3), 10: (256, 256, 3)}
CHANNELS = (64, 192, 384, 256, 256)
SLICE = {0: 1, 3: 2, 6: 3, 8: 4, 10: 5}


def random_weights(seed: int = 0):
    """(torchvision alexnet state dict incl. classifier keys, lpips v0.1 alex.pth state dict)."""
    g = torch.Generator().manual_seed(seed)
    tv = {}
    for i, (o, c, k) in CONVS.items():
        tv[f"features.{i}.weight"] = torch.randn(o, c, k, k, generator=g) * (2.0 / (c * k * k)) ** 0.5
        tv[f"features.{i}.bias"] = 0.1 * torch.randn(o, generator=g)
    tv["classifier.1.weight"] = torch.randn(8, 4, generator=g)  # ignored, like torchvision's classifier
    tv["classifier.1.bias"] = torch.randn(8, generator=g)
    lin = {f"lin{k}.model.1.weight": torch.rand(1, c, 1, 1, generator=g) / c for k, c in enumerate(CHANNELS)}
    return tv, lin


def reference_lpips(x0: torch.Tensor, x1: torch.Tensor, tv: dict, lin: dict) -> torch.Tensor:
    """LPIPS v0.1 written out with torch.nn.functional, in float64. x0, x1 in [0, 1]."""
    shift = torch.tensor([-0.030, -0.088, -0.188], dtype=torch.float64).view(1, 3, 1, 1)
    scale = torch.tensor([0.458, 0.448, 0.450], dtype=torch.float64).view(1, 3, 1, 1)
    W = {k: v.double() for k, v in tv.items()}

    def taps(x):
        x = (x.double() * 2 - 1 - shift) / scale
        h1 = F.relu(F.conv2d(x, W["features.0.weight"], W["features.0.bias"], stride=4, padding=2))
        h2 = F.relu(F.conv2d(F.max_pool2d(h1, 3, 2), W["features.3.weight"], W["features.3.bias"], padding=2))
        h3 = F.relu(F.conv2d(F.max_pool2d(h2, 3, 2), W["features.6.weight"], W["features.6.bias"], padding=1))
        h4 = F.relu(F.conv2d(h3, W["features.8.weight"], W["features.8.bias"], padding=1))
        h5 = F.relu(F.conv2d(h4, W["features.10.weight"], W["features.10.bias"], padding=1))
        return [h1, h2, h3, h4, h5]

    total = 0.0
    for k, (a, b) in enumerate(zip(taps(x0), taps(x1))):
        na = a / (torch.sqrt((a**2).sum(1, keepdim=True)) + 1e-10)
        nb = b / (torch.sqrt((b**2).sum(1, keepdim=True)) + 1e-10)
        w = lin[f"lin{k}.model.1.weight"].double().view(1, -1, 1, 1)
        total = total + ((na - nb) ** 2 * w).sum(1).mean(dim=(1, 2))
    return total


@pytest.fixture(scope="module")
def weights():
    return random_weights(0)


@pytest.fixture()
def weight_files(tmp_path, weights):
    tv, lin = weights
    torch.save(tv, tmp_path / "alexnet.pth")
    torch.save(lin, tmp_path / "alex.pth")
    return tmp_path


def images(B=2, H=64, W=72, seed=1):
    g = torch.Generator().manual_seed(seed)
    x0 = torch.rand(B, 3, H, W, generator=g)
    x1 = (x0 + 0.2 * torch.randn(B, 3, H, W, generator=g)).clamp(0, 1)
    return x0, x1


def test_forward_matches_functional_reference(weight_files, weights):
    model = LPIPS.from_files(weight_files / "alexnet.pth", weight_files / "alex.pth")
    assert not model.training and not any(p.requires_grad for p in model.parameters())
    x0, x1 = images()
    got = model(x0, x1)
    want = reference_lpips(x0, x1, *weights)
    assert got.shape == (2,) and not got.requires_grad
    torch.testing.assert_close(got.double(), want, rtol=1e-4, atol=1e-7)
    # float64 model: tight agreement (its shift/scale constants are float32-rounded, hence not 1e-15)
    torch.testing.assert_close(model.double()(x0.double(), x1.double()), want, rtol=1e-7, atol=1e-12)


def test_identical_images_give_zero(weight_files):
    model = LPIPS.from_files(weight_files / "alexnet.pth", weight_files / "alex.pth")
    x0, _ = images(B=3, H=40, W=40)
    assert torch.equal(model(x0, x0.clone()), torch.zeros(3))
    for v in (0.0, 1.0):
        c = torch.full((1, 3, 32, 32), v)
        assert model(c, c.clone()).item() == 0.0


def test_combined_layouts_give_the_same_model(tmp_path, weight_files, weights):
    tv, lin = weights
    x0, x1 = images(B=1)
    ref = LPIPS.from_files(weight_files / "alexnet.pth", weight_files / "alex.pth")(x0, x1)
    # a saved lpips.LPIPS module: net.slice{k}.{i}.*, lin{k}.model.1.weight and lins.{k}.model.1.weight
    lp = {}
    for key, v in tv.items():
        if key.startswith("features."):
            i = int(key.split(".")[1])
            lp[f"net.slice{SLICE[i]}.{key[len('features.'):]}"] = v
    lp.update(lin)
    lp.update({f"lins.{k}.model.1.weight": v for k, v in enumerate(lin.values())})
    lp["scaling_layer.shift"] = torch.zeros(1, 3, 1, 1)
    torch.save(lp, tmp_path / "lpips_module.pth")
    assert torch.equal(LPIPS.from_files(tmp_path / "lpips_module.pth")(x0, x1), ref)
    # our own state dict, wrapped and prefixed as DataParallel checkpoints often are
    own = LPIPS.from_files(weight_files / "alexnet.pth", weight_files / "alex.pth").state_dict()
    torch.save({"state_dict": {f"module.{k}": v for k, v in own.items()}}, tmp_path / "own.pth")
    assert torch.equal(LPIPS.from_files(tmp_path / "own.pth")(x0, x1), ref)
    # lin without dropout: lin{k}.model.0.weight
    torch.save({k.replace("model.1", "model.0"): v for k, v in lin.items()}, tmp_path / "alex_nodrop.pth")
    assert torch.equal(LPIPS.from_files(weight_files / "alexnet.pth", tmp_path / "alex_nodrop.pth")(x0, x1), ref)
    assert set(load_lpips_state_dict(weight_files / "alexnet.pth", weight_files / "alex.pth")) == set(own)


def test_differentiable_when_asked(weight_files):
    model = LPIPS.from_files(weight_files / "alexnet.pth", weight_files / "alex.pth")
    x0, x1 = images(B=2, H=48, W=48)
    pred = x0.clone().requires_grad_(True)
    loss = model(pred, x1).sum()
    loss.backward()
    assert pred.grad is not None and torch.isfinite(pred.grad).all() and pred.grad.abs().sum() > 0
    assert all(p.grad is None for p in model.parameters())
    # flat images (many zero feature vectors after the ReLUs) still give finite gradients
    for v in (0.0, 1.0):
        flat = torch.full((1, 3, 40, 40), v, requires_grad=True)
        model(flat, x1[:1, :, :40, :40]).sum().backward()
        assert torch.isfinite(flat.grad).all()


def test_input_errors(weight_files):
    model = LPIPS()
    x = torch.rand(1, 3, 40, 40)
    with pytest.raises(ValueError, match="too small"):
        model(x[..., :20, :20], x[..., :20, :20])
    with pytest.raises(ValueError, match=r"pred: expected a tensor \[B, 3, H, W\]"):
        model(x[:, :1], x)
    with pytest.raises(ValueError, match="shapes differ"):
        model(x, torch.rand(2, 3, 40, 40))


def test_missing_and_malformed_files_give_clear_errors(tmp_path, weight_files, weights):
    tv, lin = weights
    missing = tmp_path / "nope.pth"
    with pytest.raises(FileNotFoundError, match=r"backbone weights: file not found: .*nope\.pth"):
        LPIPS.from_files(missing, weight_files / "alex.pth")
    with pytest.raises(FileNotFoundError, match=r"lin weights: file not found: .*nope\.pth"):
        LPIPS.from_files(weight_files / "alexnet.pth", missing)
    # backbone and lin swapped: the missing key and the path are named
    with pytest.raises(ValueError, match=r"backbone weights: .*alex\.pth: missing key 'features\.0\.weight'"):
        LPIPS.from_files(weight_files / "alex.pth", weight_files / "alexnet.pth")
    bad = dict(lin)
    del bad["lin3.model.1.weight"]
    torch.save(bad, tmp_path / "lin_missing.pth")
    with pytest.raises(ValueError, match=r"lin_missing\.pth: missing key 'lin3\.model\.1\.weight'"):
        LPIPS.from_files(weight_files / "alexnet.pth", tmp_path / "lin_missing.pth")
    wrong = dict(tv)
    wrong["features.6.weight"] = torch.zeros(384, 192, 5, 5)
    torch.save(wrong, tmp_path / "wrong_shape.pth")
    msg = r"wrong_shape\.pth: key 'features\.6\.weight' has shape \(384, 192, 5, 5\), expected \(384, 192, 3, 3\)"
    with pytest.raises(ValueError, match=msg):
        LPIPS.from_files(tmp_path / "wrong_shape.pth", weight_files / "alex.pth")
    (tmp_path / "garbage.pth").write_bytes(b"not a torch file at all")
    with pytest.raises(ValueError, match=r"garbage\.pth is not a loadable state dict"):
        LPIPS.from_files(tmp_path / "garbage.pth", weight_files / "alex.pth")
    torch.save(torch.zeros(3), tmp_path / "tensor.pth")
    with pytest.raises(ValueError, match=r"tensor\.pth holds a Tensor, expected a state dict"):
        LPIPS.from_files(weight_files / "alexnet.pth", tmp_path / "tensor.pth")
    # a checkpoint carrying an arbitrary object is refused by weights_only=True, not unpickled
    torch.save({"lin0.model.1.weight": fractions.Fraction(1, 3)}, tmp_path / "evil.pth")
    msg = r"evil\.pth is not a loadable state dict \(refused by torch.load\(weights_only=True\)"
    with pytest.raises(ValueError, match=msg):
        LPIPS.from_files(tmp_path / "evil.pth", weight_files / "alex.pth")
    nan = dict(lin)
    nan["lin0.model.1.weight"] = torch.full((1, 64, 1, 1), float("nan"))
    torch.save(nan, tmp_path / "nan.pth")
    with pytest.raises(ValueError, match=r"nan\.pth: key 'lin0\.model\.1\.weight' is not a finite"):
        LPIPS.from_files(weight_files / "alexnet.pth", tmp_path / "nan.pth")


def test_find_lpips_weights(monkeypatch, tmp_path, weight_files):
    monkeypatch.delenv(ENV_VAR, raising=False)
    assert find_lpips_weights() is None
    assert load_lpips() is None
    assert "TRIOMAN_LPIPS_DIR" in NOT_FOUND_MESSAGE
    monkeypatch.setenv(ENV_VAR, "")
    assert find_lpips_weights() is None

    monkeypatch.setenv(ENV_VAR, str(weight_files))
    paths = find_lpips_weights()
    assert paths.backbone == weight_files / "alexnet.pth" and paths.lin == weight_files / "alex.pth"
    model = load_lpips()
    x0, x1 = images(B=1, H=36, W=36)
    assert torch.equal(model(x0, x1), LPIPS.from_dir(weight_files)(x0, x1))

    # torchvision's download name is accepted for the backbone
    tvdir = tmp_path / "tv"
    tvdir.mkdir()
    (weight_files / "alexnet.pth").rename(tvdir / "alexnet-owt-7be5be79.pth")
    (weight_files / "alex.pth").rename(tvdir / "alex.pth")
    assert find_lpips_weights(tvdir).backbone.name == "alexnet-owt-7be5be79.pth"

    # a combined file
    combined = tmp_path / "combined"
    combined.mkdir()
    torch.save(model.state_dict(), combined / "lpips_alex.pth")
    monkeypatch.setenv(ENV_VAR, str(combined))
    assert find_lpips_weights() == (combined / "lpips_alex.pth", None)
    assert torch.equal(load_lpips()(x0, x1), model(x0, x1))

    # named but wrong: a clear error, not a silent None
    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / "alex.pth").write_bytes(b"")
    monkeypatch.setenv(ENV_VAR, str(empty))
    with pytest.raises(FileNotFoundError, match=r"TRIOMAN_LPIPS_DIR: .*empty lacks the LPIPS weights: missing alexnet\.pth"):
        find_lpips_weights()
    monkeypatch.setenv(ENV_VAR, str(tmp_path / "missing_dir"))
    with pytest.raises(FileNotFoundError, match=r"TRIOMAN_LPIPS_DIR: LPIPS weights folder not found: .*missing_dir"):
        find_lpips_weights()
