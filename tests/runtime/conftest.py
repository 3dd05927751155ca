"""Fixtures of the runtime's tests. Torch stays out of this module: the fixtures that need it import it themselves
(and skip without it), so the torch-free tests collect and run without torch."""

from pathlib import Path
from types import SimpleNamespace

import pytest

from tests.runtime.factories import write


@pytest.fixture
def avatar_dir(tmp_path):
    """A random avatar folder (tests.runtime.factories.write) at ``tmp_path / "avatars" / "a"``."""
    write(tmp_path / "avatars")
    return tmp_path / "avatars" / "a"


@pytest.fixture(scope="module")
def inputs(tiny_run, tmp_path_factory):
    """A tiny exported avatar and its subject, tiny Refiner and Examiner ONNX files and an avatar of another body
    (tests/runtime/test_augment.py, tests/runtime/test_shards.py); torch and onnx build them. refiner16.onnx is exported
    at 16x16 (it takes any size), refiner16_fixed.onnx the same as exported before `trioman.size_multiple`: 16x16 only."""
    torch = pytest.importorskip("torch")
    pytest.importorskip("onnx")
    from tests.export.factories import trained_like
    from tests.runtime.factories import fixed_size_copy
    from tests.toolkit.avatar.factories import SMALL
    from tests.toolkit.examiner.helpers import TINY
    from tests.toolkit.refiner.helpers import open_zero_inits, tiny_config
    from trioman.cli import main
    from trioman.export.avatar import export_model
    from trioman.export.onnx_models import export_examiner_onnx, export_refiner_onnx
    from trioman.runtime.formats import load_avatar
    from trioman.toolkit.avatar.model import AvatarConfig
    from trioman.toolkit.examiner import create_examiner
    from trioman.toolkit.refiner import create_refiner

    root = tmp_path_factory.mktemp("augment")
    avatar = root / "avatar"
    assert main(["export", "avatar", str(tiny_run), "--out", str(avatar)]) == 0
    subject = Path(load_avatar(avatar).meta["source"]["subject"])
    models = {}
    for name, conditions, size in (("refiner", "tex+geo", 32), ("refiner_none", "none", 32), ("refiner16", "tex+geo", 16),
                                   ("refiner_warp", "warp+geo", 32)):
        model = open_zero_inits(create_refiner(tiny_config(conditions=conditions)), std=0.2)
        export_refiner_onnx(model, root / f"{name}.onnx", size=size, gate_frames=2)
        models[name] = root / f"{name}.onnx"
    models["refiner16_fixed"] = fixed_size_copy(models["refiner16"], root / "refiner16_fixed.onnx")
    torch.manual_seed(0)
    ex = create_examiner(TINY)
    with torch.no_grad():  # spread the scores away from 0.5
        for p in ex.parameters():
            p.add_(0.3 * torch.randn_like(p))
    export_examiner_onnx(ex, root / "examiner.onnx", gate_frames=2)
    export_model(trained_like(AvatarConfig(**SMALL)), root / "other_avatar", body_model="test")  # a 4-joint body
    return SimpleNamespace(root=root, subject=subject, avatar=avatar, examiner=root / "examiner.onnx",
                           other_avatar=root / "other_avatar", **models)


@pytest.fixture(scope="module")
def straight(inputs):
    """The augment run of ``inputs`` with the tests' settings: its folder, its result and a snapshot of its files."""
    from tests.runtime.augment_runs import run, snapshot

    out = inputs.root / "straight"
    result = run(inputs, out)
    return SimpleNamespace(out=out, result=result, files=snapshot(out))
