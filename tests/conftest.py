"""Shared test helpers, and the fixtures that tests in more than one package use."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

import pytest

# Prepended to a subprocess's code: makes ``import torch`` fail the way it does where torch is
# not installed (importlib.util.find_spec also reports it missing).
BLOCK_TORCH = "import sys; sys.modules['torch'] = None\n"

# TRIOMAN_TEST_WITHOUT_TORCH=1: the suite as on a machine without torch (`make test` runs tests/runtime so): the
# runtime's tests pass there, and those that compare with a torch model skip, each on its own.
if os.environ.get("TRIOMAN_TEST_WITHOUT_TORCH") == "1":
    sys.modules["torch"] = None


def run_python(code: str, block_torch: bool = False, timeout: float = 120) -> subprocess.CompletedProcess:
    """Run ``code`` in a fresh interpreter; returns the completed process (text output)."""
    src = (BLOCK_TORCH if block_torch else "") + textwrap.dedent(code)
    return subprocess.run([sys.executable, "-c", src], capture_output=True, text=True, timeout=timeout)


@pytest.fixture(scope="session")
def anny_body():
    """The default Anny body in float64 (builds Anny's cache on first use, ~2 min once)."""
    torch = pytest.importorskip("torch")
    pytest.importorskip("anny")
    from trioman.toolkit.body.registry import create_body_model

    return create_body_model("anny", phenotype={"height": 0.7, "weight": 0.3}, dtype=torch.float64)


def skip_without_person_models() -> None:
    """Skip the calling test module when `trioman fit`'s person models (LiteRT and the mediapipe 0.10.21 wheel's
    .tflite files, which `make install` adds) are not installed; its call sits at module level."""
    pytest.importorskip("ai_edge_litert")
    from trioman.runtime.person import MissingModelsError, load_models

    try:
        load_models()
    except MissingModelsError as exc:
        pytest.skip(f"person models not installed: {exc}", allow_module_level=True)


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    """A tiny trained run: 3 steps on a 6-frame synthetic Anny subject (tests/export,
    tests/toolkit/refiner/test_sd_turbo.py)."""
    pytest.importorskip("torch")
    pytest.importorskip("anny")
    from trioman.toolkit.avatar.model import AvatarConfig
    from trioman.toolkit.synth.subject import SynthConfig, synthesize_subject
    from trioman.toolkit.train.config import TrainConfig
    from trioman.toolkit.train.loop import train

    root = tmp_path_factory.mktemp("export_run")
    synthesize_subject(SynthConfig(seed=5, size=32, frames=6, texture_size=64), root / "s", progress=False)
    cfg = TrainConfig(iterations=3, checkpoint_every=3, lr=1e-2,
                      avatar=AvatarConfig(keep=0.05, triplane_channels=4, triplane_res=8, hidden=8))
    return train(root / "s", root / "run", cfg, progress=False)


@pytest.fixture(scope="module")
def corpus(tmp_path_factory):
    """A fabricated corpus: two training subjects and one held out, random triplet files
    (tests.toolkit.factories.fake_triplets; tests/toolkit/corpus/test_training.py, tests/toolkit/refiner/test_sd_turbo.py,
    tests/bench/test_deploy.py)."""
    from tests.toolkit.factories import fake_triplets
    from trioman.toolkit.corpus.build import CORPUS_JSON

    root = tmp_path_factory.mktemp("corpus")
    subjects = [{"name": "s00", "role": "train"}, {"name": "s01", "role": "train"}, {"name": "s02", "role": "heldout"}]
    for s in subjects:
        folder = root / "triplets" / ("all" if s["role"] == "train" else "heldout")
        folder.mkdir(parents=True, exist_ok=True)
        fake_triplets(folder / f"{s['name']}.npz", seed=len(s["name"]) + int(s["name"][1:]))
    (root / CORPUS_JSON).write_text(json.dumps({"config": {}, "subjects": subjects}))
    return root
