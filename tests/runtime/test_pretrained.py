"""runtime/pretrained.py: the shipped Refiner and Examiner load in the torch-free runtime, match their record, and a
missing or altered file is a clear error."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from trioman.runtime import pretrained
from trioman.runtime.onnx_models import ExaminerModel, RefinerModel, load_model
from trioman.runtime.formats.common import FormatError


def test_the_shipped_models_match_their_record_and_budget():
    record = pretrained.read_record()
    assert set(record["models"]) == set(pretrained.KINDS)
    assert sum(e["bytes"] for e in record["models"].values()) <= 25 * 10**6
    assert record["card"] == "docs/models.md"
    for kind in pretrained.KINDS:
        path = pretrained.shipped_path(kind)  # checks bytes and sha256
        assert path.parent == pretrained.PRETRAINED_DIR
        assert record["models"][kind]["precision"] == "fp32"


def test_the_shipped_refiner_runs_within_its_recorded_parity():
    entry = pretrained.read_record()["models"]["refiner"]
    model = load_model(pretrained.shipped_path("refiner"), kind="refiner")
    assert isinstance(model, RefinerModel)
    assert model.conditions == entry["conditions"] == "warp+geo"
    assert entry["parity_max_abs"] <= 1e-3  # docs/design.md, "Deployment": the Refiner's fp32 tolerance
    H, W = model.size
    rng = np.random.default_rng(0)
    coarse, ref, normal = (rng.random((2, H, W, 3), dtype=np.float32) for _ in range(3))
    out = model.refine(coarse, reference=ref, normal=normal)
    assert out.shape == (2, H, W, 3) and np.isfinite(out).all() and out.min() >= 0 and out.max() <= 1


def test_the_shipped_examiner_scores_any_size_the_same_alone_or_in_a_batch():
    model = load_model(pretrained.shipped_path("examiner"), kind="examiner")
    assert isinstance(model, ExaminerModel)
    rng = np.random.default_rng(0)
    real = rng.random((96, 80, 3), dtype=np.float32)  # not the model's size: resized to it
    candidates = np.stack([real, np.clip(real + 0.2 * rng.standard_normal(real.shape), 0, 1).astype(np.float32)])
    scores = model.score(candidates, real)
    assert scores.shape == (2,) and np.isfinite(scores).all() and ((scores >= 0) & (scores <= 1)).all()
    alone = np.concatenate([model.score(c[None], real) for c in candidates])
    np.testing.assert_allclose(scores, alone, atol=1e-5)


def test_the_record_holds_the_held_out_quality():
    q = pretrained.read_record()["heldout"]
    assert q["test_frames"] > 0 and len(q["subjects"]) >= 2
    assert abs(q["refiner_gain_db"] - (q["psnr_refined_db"] - q["psnr_render_db"])) <= 0.002
    # a warp+geo Refiner: its aligned input is measured too (the bar it must clear, docs/models.md)
    assert abs(q["refiner_gain_over_aligned_db"] - (q["psnr_refined_db"] - q["psnr_aligned_db"])) <= 0.002
    # well above chance on subjects it never saw (a constant-scoring Examiner, as the first one shipped, lands near 0.5)
    assert 0.6 < q["examiner_auroc_real_vs_render"] <= 1


def test_resolve_model_values():
    assert pretrained.resolve_model(None, "refiner") is None
    assert pretrained.resolve_model("none", "examiner") is None
    assert pretrained.resolve_model("shipped", "refiner") == pretrained.shipped_path("refiner")
    assert str(pretrained.resolve_model("a/b.onnx", "refiner")) == "a/b.onnx"
    with pytest.raises(ValueError, match="kind"):
        pretrained.shipped_path("generator")


def _copy(tmp_path):
    dest = tmp_path / "pretrained"
    shutil.copytree(pretrained.PRETRAINED_DIR, dest, ignore=shutil.ignore_patterns("__pycache__"))
    return dest


def test_an_altered_file_is_refused(tmp_path):
    dest = _copy(tmp_path)
    data = bytearray((dest / "refiner.onnx").read_bytes())
    data[len(data) // 2] ^= 0xFF
    (dest / "refiner.onnx").write_bytes(bytes(data))
    with pytest.raises(FormatError, match=r"refiner\.onnx: not the shipped refiner"):
        pretrained.shipped_path("refiner", dest)
    pretrained.shipped_path("examiner", dest)  # the other one still loads


def test_a_missing_file_or_record_is_named(tmp_path):
    dest = _copy(tmp_path)
    (dest / "examiner.onnx").unlink()
    with pytest.raises(FormatError, match=r"examiner\.onnx: missing file"):
        pretrained.shipped_path("examiner", dest)
    (dest / pretrained.RECORD).unlink()
    with pytest.raises(FormatError, match="models.json: missing file"):
        pretrained.shipped_path("refiner", dest)


@pytest.mark.parametrize("field, value, match", [
    ("format", "other", "format"),
    ("file", "../refiner.onnx", r"models\.refiner\.file"),
    ("sha256", "abc", r"models\.refiner\.sha256"),
    ("bytes", 0, r"models\.refiner\.bytes"),
])
def test_a_malformed_record_is_named(tmp_path, field, value, match):
    dest = _copy(tmp_path)
    record = json.loads((dest / pretrained.RECORD).read_text())
    if field == "format":
        record["format"] = value
    else:
        record["models"]["refiner"][field] = value
    (dest / pretrained.RECORD).write_text(json.dumps(record))
    with pytest.raises(FormatError, match=match):
        pretrained.shipped_path("refiner", dest)
