"""``trioman bench train`` end to end at a tiny size: curves, hole measure, step profile, pictures and the report."""

import json

import pytest

pytest.importorskip("torch")
pytest.importorskip("anny")

from trioman.cli import main  # noqa: E402


def test_bench_train_writes_curves_holes_and_report(tmp_path, monkeypatch):
    out = tmp_path / "bench"
    assert main(["bench", "train", "--out", str(out), "--size", "32", "--frames", "10", "--presets", "quick",
                 "--iterations", "4", "--eval-every", "2", "--repeats", "1", "--threads", "1"]) == 0
    report = json.loads((out / "train.json").read_text())
    q = report["presets"]["quick"]
    assert q["iterations"] == 4 and [c["step"] for c in q["curve"]] == [2, 4]
    for point in q["curve"]:
        assert point["train_seconds"] > 0 and all(0 < point[k] < 100 for k in ("train_psnr", "test_psnr"))
    assert 0 <= q["hole_fraction"] <= 1 and q["gaussians"] > 0
    assert q["best_test_psnr"] == max(c["test_psnr"] for c in q["curve"])
    assert [r["size"] for r in report["rasterizer"]] == [16, 32]
    from trioman.bench.train import STAGES

    profile = report["step_profile"]
    assert [(r["size"], r["threads"]) for r in profile] == [(16, 1), (32, 1)]
    for row in profile:
        # every mark of the step is one of STAGES (another shows under its own name) and each was hit; the marks
        # never overlap (their sum fits in the step) and cover most of it ("other" is what lies outside them)
        assert list(row["stages"]) == [*STAGES, "other"] and all(v > 0 for v in row["stages"].values()), row
        assert abs(sum(row["stages"].values()) - row["step_s"]) < 1e-9
        assert row["stages"]["other"] < 0.25 * row["step_s"], row
    check_step_time_against_the_clock(out / "subject", monkeypatch)
    md = (out / "train.md").read_text()
    assert "holes at 512 px" in md and "2: " in md and "| rasterizer backward |" in md
    assert {row["rasterizer"] for row in report["step_profile"]} <= {"C kernel", "torch"}
    assert f"rasterizer: {report['step_profile'][0]['rasterizer']})" in md
    for name in ("train_psnr_vs_time.png", "render_quick_512.png", "step_profile.png"):
        assert (out / name).stat().st_size > 1000


def check_step_time_against_the_clock(subject, monkeypatch, steps=3, warmup=2):
    """profile_step's step time against each timed call of the training step, clocked here: the step time covers the
    call (and the frame sampling beside it, a small share); the marked stages lie inside the calls."""
    import time

    import trioman.toolkit.train.loop as loop
    from trioman.bench.train import profile_step

    calls, real = [], loop.train_step

    def clocked(*args, **kw):
        t0 = time.perf_counter()
        result = real(*args, **kw)
        calls.append(time.perf_counter() - t0)
        return result

    monkeypatch.setattr(loop, "train_step", clocked)
    (row,) = profile_step(subject, "quick", (16,), (1,), steps, warmup)
    assert len(calls) == warmup + steps
    clock = sum(calls[warmup:]) / steps
    assert clock <= row["step_s"] < 1.1 * clock + 1e-3, (row["step_s"], clock)
    assert sum(v for k, v in row["stages"].items() if k != "other") <= clock, (row, clock)
