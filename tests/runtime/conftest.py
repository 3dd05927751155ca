"""Fixtures of the runtime's tests. Torch stays out of this module: the fixtures that need it import it themselves
(and skip without it), so the torch-free tests collect and run without torch."""

from types import SimpleNamespace

import pytest

from tests.runtime.factories import write


@pytest.fixture
def avatar_dir(tmp_path):
    """A random avatar folder (tests.runtime.factories.write) at ``tmp_path / "avatars" / "a"``."""
    write(tmp_path / "avatars")
    return tmp_path / "avatars" / "a"


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    """A subject, its avatar, an avatar of another body, the shipped Examiner and Refiner (warp+geo) and block Refiners
    (tests.runtime.augment_inputs.make_inputs: tests/runtime/test_augment.py, tests/runtime/test_shards.py); built
    without torch, the Refiners with onnx."""
    pytest.importorskip("onnx")
    from tests.runtime.augment_inputs import make_inputs

    return make_inputs(tmp_path_factory.mktemp("augment"))


@pytest.fixture(scope="module")
def straight(inputs):
    """The augment run of ``inputs`` with the tests' settings: its folder, its result and a snapshot of its files."""
    from tests.runtime.augment_runs import run, snapshot

    out = inputs.root / "straight"
    result = run(inputs, out)
    return SimpleNamespace(out=out, result=result, files=snapshot(out))
