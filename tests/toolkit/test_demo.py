"""The demo end to end at a tiny size (slow: ~1.5 min; `make test-all`)."""

import json

import pytest

pytest.importorskip("torch")
pytest.importorskip("anny")

from trioman.cli import main  # noqa: E402
from trioman.runtime.formats import load_avatar, load_subject  # noqa: E402


@pytest.mark.slow
def test_demo_runs_export_and_augment(tmp_path, capsys):
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out), "--size", "64", "--frames", "12", "--iterations", "30",
                 "--model-steps", "5", "--augment-frames", "2", "--quiet"]) == 0
    printed = capsys.readouterr().out
    assert f"pseudo-GT     {out / 'augmented'}" in printed and str(out / "onnx" / "export.json") in printed
    load_avatar(out / "avatar")
    assert (out / "onnx" / "refiner.onnx").is_file() and (out / "onnx" / "examiner.onnx").is_file()
    result = json.loads((out / "augmented" / "augment.json").read_text())
    assert result["summary"]["source_frames"] == 2 and result["summary"]["accepted"] == 2
    assert load_subject(out / "augmented").num_frames == 2
    assert (out / "animate_walk.mp4").stat().st_size > 0
