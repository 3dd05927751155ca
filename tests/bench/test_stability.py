"""``trioman bench stability`` at a tiny size: every group reported, finite, within its tolerance; and how a
training run's outcome is read (ended, stopped by the guard, weights refused)."""

import json

import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("onnx")

from trioman.bench.stability import LoopOutcome, loop_outcome  # noqa: E402
from trioman.cli import main  # noqa: E402
from trioman.export.onnx_models import EXAMINER_ATOL, REFINER_ATOL  # noqa: E402
from trioman.toolkit.loops.checkpoint import save_checkpoint  # noqa: E402
from trioman.toolkit.loops.guard import StepGuard, check_weights  # noqa: E402

ONNX = "Refiner and Examiner, ONNX variants on extreme images"
TRAINING = "training loops at 1x and 100x the default learning rate"


def test_bench_stability_reports_every_case(tmp_path, capsys):
    out = tmp_path / "bench"
    assert main(["bench", "stability", "--out", str(out), "--seeds", "1", "--iterations", "1"]) == 0
    report = json.loads((out / "stability.json").read_text())
    rows = report["rows"]
    groups = {r["group"] for r in rows}
    assert {"renderer vs float64 oracle", "rasterizer gradients", "Refiner and Examiner, float32 vs float64", ONNX,
            "axis-angle -> matrix vs expm", TRAINING} <= groups
    fk = [r for r in rows if r["group"].startswith("FK + LBS")]
    assert {r["method"] for r in fk} == {"numpy float64", "torch float32", "torch float64"}
    assert report["all_finite"] and all(r["finite"] for r in rows)
    for r in rows:
        if r["group"] in ("renderer vs float64 oracle", "rasterizer gradients", "Refiner and Examiner, float32 vs float64"):
            assert r["worst_error"] < 1e-4, r
        elif r["group"].startswith(("axis-angle", "FK + LBS")):
            assert r["worst_error"] < (1e-12 if r["method"].endswith("float64") else 1e-4), r
    onnx = {(r["case"], r["method"]): r for r in rows if r["group"] == ONNX}
    for model, atol in (("Refiner (tex+geo)", REFINER_ATOL), ("Examiner (examiner_nano layout)", EXAMINER_ATOL)):
        assert onnx[model, "onnxruntime fp32 vs torch float32"]["worst_error"] <= atol
        for precision in ("fp16", "int8"):  # written by the export (the tiny models pass its gates), every output finite
            assert onnx[model, f"onnxruntime {precision} vs fp32"]["worst_error"] < 0.1
    training = [r for r in rows if r["group"] == TRAINING]
    assert [r["case"] for r in training] == [f"{loop}, learning rate x{f} ({lr:g})" for loop, lrs in
                                             (("avatar", (1e-3, 0.1)), ("Refiner", (2e-4, 2e-2)), ("Examiner", (3e-4, 3e-2)))
                                             for f, lr in zip((1, 100), lrs)]
    for r in training:  # the tiny runs end: weights finite, nothing skipped, no message
        assert (r["finite"], r["skipped"], r["stopped"]) == (True, 0, ""), r
        assert "1 losses, 0 steps skipped by the guard; ended" in r["note"]
    md = (out / "stability.md").read_text()
    assert "| 1e4 m scene from 1e4 times farther | numpy float32 |" in md and "Every output finite: yes." in md
    assert "| Examiner (examiner_nano layout) | onnxruntime int8 vs fp32 |" in md
    assert f"bench: report {out / 'stability.md'}" in capsys.readouterr().out


def test_loop_outcome_reads_ended_stopped_and_refused_runs(tmp_path):
    model = torch.nn.Linear(2, 2)

    def ended():
        save_checkpoint(tmp_path / "ended", 2, {"step": 2, "model": {}, "config": {}, "skipped": 1})
        return "result"

    assert loop_outcome(ended, tmp_path / "ended") == LoopOutcome("result", "", 1, True)

    def stopped_by_guard():
        guard = StepGuard("refiner", max_consecutive=2, skipped=3)
        for step in range(2):
            guard.finite_ok(torch.tensor(float("nan")), step, hint="Lower the learning rate (lr=0.02).")

    outcome = loop_outcome(stopped_by_guard, tmp_path / "guard")
    assert outcome.result is None and (outcome.skipped, outcome.weights_finite) == (5, True)
    assert outcome.stopped.startswith("refiner: 2 consecutive steps (the last, step 2,") and "lr=0.02" in outcome.stopped

    def refused():
        save_checkpoint(tmp_path / "refused", 3, {"step": 3, "model": {}, "config": {}, "skipped": 2})
        with torch.no_grad():
            model.weight.fill_(float("inf"))
        check_weights(model, "examiner", 4, tmp_path / "refused" / "checkpoints" / "ckpt_0000003.pt")

    outcome = loop_outcome(refused, tmp_path / "refused")
    assert (outcome.skipped, outcome.weights_finite) == (2, False) and "weights at step 4 are not finite" in outcome.stopped
