"""Shared test helpers."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest

# Prepended to a subprocess's code: makes ``import torch`` fail the way it does where torch is
# not installed (importlib.util.find_spec also reports it missing).
BLOCK_TORCH = "import sys; sys.modules['torch'] = None\n"


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
