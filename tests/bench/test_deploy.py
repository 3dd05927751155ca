"""`bench deploy` pieces on tiny trained models and a fabricated corpus: every variant row is measured
against the torch fp32 reference, the table and the scatter plot are written."""

import json

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("onnx")

from trioman.bench.scenes import random_scene  # noqa: E402
from tests.toolkit.factories import S  # noqa: E402
from trioman.export.onnx_models import export_onnx  # noqa: E402
from trioman.bench.deploy import (  # noqa: E402
    bench_examiner_rows, bench_refiner_rows, bench_renderer_rows, deploy_markdown, scatter_plot,
)
from trioman.bench.models import ModelsBenchConfig, bench_models  # noqa: E402
from trioman.toolkit.corpus.build import triplet_paths  # noqa: E402
from trioman.toolkit.loops.checkpoint import latest_checkpoint  # noqa: E402
from trioman.toolkit.corpus.triplets import TripletSet  # noqa: E402


@pytest.fixture(scope="module")
def trained(corpus, tmp_path_factory):
    out = tmp_path_factory.mktemp("bench_models")
    bench_models(ModelsBenchConfig(corpus=str(corpus), subjects=2, heldout=1, size=S, out=str(out), refiner_steps=2,
                                   examiner_steps=2, batch=2, examiner="examiner_nano", crop=16, refiner_size="compact",
                                   baseline_frames=("all",)))
    return {k: latest_checkpoint(out / "runs" / run) for k, run in (("refiner", "refiner_tex_geo"), ("examiner", "examiner"))}


def test_model_rows_cover_every_variant(trained, corpus, tmp_path):
    onnx = tmp_path / "onnx"
    export_onnx(refiner=trained["refiner"], examiner=trained["examiner"], out=onnx, variants=("fp32", "int8", "fp16"),
                calibration=triplet_paths(corpus)["train"], size=S)
    frames = TripletSet.load(triplet_paths(corpus)["heldout"]).evaluation("test")
    rows = bench_refiner_rows(trained["refiner"], onnx, frames, repeats=1, threads=1)
    rows += bench_examiner_rows(trained["examiner"], onnx, frames, repeats=1, threads=1)
    variants = [r["variant"] for r in rows]
    for comp in ("refiner", "examiner"):
        assert sum(v.startswith("onnxruntime fp32") for r, v in zip(rows, variants) if r["component"] == comp) == 4
    measured = [r for r in rows if r["ms"] is not None]
    assert all(r["ms"] > 0 and np.isfinite(r["error"]) for r in measured)
    fp32 = [r for r in measured if "fp32," in r["variant"]]
    assert all(r["error"] <= (1e-3 if r["component"] == "refiner" else 1e-4) for r in fp32)  # docs/design.md, Deployment
    assert all(r["agreement"] == 1.0 for r in fp32 if r["component"] == "examiner")
    rejected = json.loads((onnx / "export.json").read_text())["rejected"]
    assert all(("note" in r) == (r["ms"] is None) for r in rows) and len(rows) - len(measured) == len(rejected)

    report = {"rows": rows + bench_renderer_rows(small_scene(), 24, repeats=1, oracle_size=16), "torch_threads": 1,
              "ort_threads": 1, "frames": len(frames.gt), "model_size": S, "render_size": 24, "export_s": 1.0,
              "figure": str(tmp_path / "deploy.png"),
              "augment": {"subject": "s02", "frames": 2, "candidates": 4, "accepted": 2,
                          "ms_per_frame": {"render": 1.0, "refine": 2.0, "total": 3.0}}}
    scatter_plot(report["rows"], tmp_path / "deploy.png")
    assert (tmp_path / "deploy.png").stat().st_size > 1000
    md = deploy_markdown(report)
    assert "| renderer | numpy tile 4, opacity extent (24px) |" in md and "| refine | 2.0 |" in md


def small_scene() -> dict:
    s = random_scene(1, n=60, width=24, height=24)
    K = np.asarray(s["K"], np.float64)
    return {k: np.asarray(s[k], np.float32) for k in ("means", "quats", "scales", "opacities", "colors", "viewmat")} | {
        "K": K * np.array([[24 / (2 * K[0, 2])], [24 / (2 * K[0, 2])], [1.0]]), "source": "random"}


def test_renderer_rows_measure_error_against_torch():
    rows = bench_renderer_rows(small_scene(), 24, repeats=1, oracle_size=16)
    by = {r["variant"]: r for r in rows}
    assert by["torch fp32 tiled fwd (24px, reference)"]["error"] == 0.0
    exact = [r for v, r in by.items() if "opacity extent" in v]
    assert len(exact) == 3 and all(r["error"] <= 1e-5 for r in exact)  # the numpy renderer matches torch
    assert all(np.isfinite(r["error"]) and r["ms"] > 0 for r in rows)
    assert any("oracle" in v for v in by)
