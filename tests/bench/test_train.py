"""``trioman bench train`` end to end at a tiny size: curves, hole measure, step profile, pictures and the report."""

import json

import pytest

pytest.importorskip("torch")
pytest.importorskip("anny")

from trioman.cli import main  # noqa: E402


def test_bench_train_writes_curves_holes_and_report(tmp_path):
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
        assert list(row["stages"]) == [*STAGES, "other"] and all(v >= 0 for k, v in row["stages"].items() if k != "other")
        assert abs(sum(row["stages"].values()) - row["step_s"]) < 1e-9 and row["stages"]["rasterizer backward"] > 0
    md = (out / "train.md").read_text()
    assert "holes at 512 px" in md and "2: " in md and "| rasterizer backward |" in md
    assert {row["rasterizer"] for row in report["step_profile"]} <= {"C kernel", "torch"}
    assert f"rasterizer: {report['step_profile'][0]['rasterizer']})" in md
    for name in ("train_psnr_vs_time.png", "render_quick_512.png", "step_profile.png"):
        assert (out / name).stat().st_size > 1000
