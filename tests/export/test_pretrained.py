"""export/pretrained.py (``trioman export pretrained``): an ``export onnx`` folder's fp32 models become a shipped
folder that runtime/pretrained.py reads back; what does not hold is refused before anything is written."""

from __future__ import annotations

import json
import shutil

import pytest

from trioman.export.pretrained import ship_pretrained
from trioman.runtime import pretrained as rt
from trioman.runtime.formats.avatar import sha256_file
from trioman.runtime.formats.common import FormatError


def _export_folder(tmp_path):
    """An ``export onnx`` folder as the exporter writes it (files, models), of the shipped files."""
    src = tmp_path / "onnx"
    src.mkdir()
    shipped = rt.read_record()["models"]
    report = {"format": "trioman-onnx-export", "trioman_version": "0", "opset": 17, "files": {}, "models": {}}
    for kind, entry in shipped.items():
        shutil.copyfile(rt.PRETRAINED_DIR / entry["file"], src / f"{kind}.onnx")
        report["files"][f"{kind}.onnx"] = {
            "model": kind, "precision": "fp32", "status": "written", "input_size": entry["input_size"],
            "parity_max_abs": entry["parity_max_abs"], "parity": {"frames_source": "triplets"},
            "bytes": entry["bytes"], "sha256": entry["sha256"]}
        report["models"][kind] = {"source": "/somewhere/on/a/machine/ckpt.pt", "step": 7, "config_hash": "h",
                                  "config": {}, **({"conditions": "warp+geo"} if kind == "refiner" else {})}
    (src / "export.json").write_text(json.dumps(report))
    return src


def test_ship_writes_a_folder_the_runtime_reads_back(tmp_path):
    src = _export_folder(tmp_path)
    dest = tmp_path / "dest"
    dest.mkdir()
    record = ship_pretrained(src, dest)
    assert record == json.loads((dest / rt.RECORD).read_text())
    for kind in rt.KINDS:
        path = rt.shipped_path(kind, dest)
        assert sha256_file(path) == sha256_file(src / f"{kind}.onnx")
        assert record["models"][kind]["step"] == 7
    assert record["models"]["refiner"]["conditions"] == "warp+geo"
    assert "/somewhere" not in (dest / rt.RECORD).read_text()  # no machine's paths in a shipped file


def test_a_file_that_differs_from_its_report_is_refused_before_writing(tmp_path):
    src = _export_folder(tmp_path)
    with open(src / "examiner.onnx", "ab") as f:
        f.write(b"\0")
    dest = tmp_path / "dest"
    dest.mkdir()
    with pytest.raises(FormatError, match=r"examiner\.onnx: missing or not the file"):
        ship_pretrained(src, dest)
    assert list(dest.iterdir()) == []


def test_a_folder_without_an_fp32_model_is_refused(tmp_path):
    src = _export_folder(tmp_path)
    report = json.loads((src / "export.json").read_text())
    report["files"]["refiner.onnx"]["precision"] = "int8"
    (src / "export.json").write_text(json.dumps(report))
    with pytest.raises(FormatError, match=r"files\.refiner\.onnx: no fp32 refiner"):
        ship_pretrained(src, tmp_path)


def test_models_over_the_budget_are_refused(tmp_path, monkeypatch):
    import trioman.export.pretrained as ship

    src = _export_folder(tmp_path)
    monkeypatch.setattr(ship, "MAX_BYTES", 1000)
    with pytest.raises(ValueError, match="MB together, over the"):
        ship_pretrained(src, tmp_path)
