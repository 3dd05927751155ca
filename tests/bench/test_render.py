"""``trioman bench render`` end to end at a tiny size: timings, differences, the stage profile and the report."""

import json

import pytest

pytest.importorskip("torch")
pytest.importorskip("anny")

from trioman.cli import main  # noqa: E402


def test_bench_render_writes_timings_stage_profile_and_report(tmp_path):
    out = tmp_path / "bench"
    assert main(["bench", "render", "--out", str(out), "--size", "32"]) == 0
    report = json.loads((out / "render.json").read_text())
    assert [r["size"] for r in report["rows"]] == [32, 64] and report["oracle"]["size"] == 16
    for row in report["rows"]:
        assert row["numpy_s"] > 0 and row["max_abs_diff_rgb"] < 1e-3
    stages = report["stages"]
    assert [(r["scene"], r["size"]) for r in stages] == [(s, n) for s in ("default", "quick", "full") for n in (32, 64)]
    assert [r["gaussians"] for r in stages[::2]] == [13718, 54848, 219368]
    for row in stages:
        assert {"projection", "tile binning", "Gaussian table", "compositing", "image"} <= set(row["stages"])
        assert abs(sum(row["stages"].values()) - row["total_ms"]) < 1e-6 and row["fps"] > 0
    md = (out / "render.md").read_text()
    assert "## The numpy renderer by stage" in md and "| full | 219368 | 64 |" in md
