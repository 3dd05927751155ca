"""``trioman bench stability`` at a tiny size: every group reported, finite, within its tolerance."""

import json

import pytest

pytest.importorskip("torch")

from trioman.cli import main  # noqa: E402


def test_bench_stability_reports_every_case(tmp_path, capsys):
    out = tmp_path / "bench"
    assert main(["bench", "stability", "--out", str(out), "--seeds", "1", "--iterations", "2"]) == 0
    report = json.loads((out / "stability.json").read_text())
    rows = report["rows"]
    groups = {r["group"] for r in rows}
    assert {"renderer vs float64 oracle", "rasterizer gradients", "Refiner and Examiner, float32 vs float64",
            "axis-angle -> matrix vs expm",
            "avatar training loop"} <= groups
    assert report["all_finite"] and all(r["finite"] for r in rows)
    for r in rows:
        if r["group"] in ("renderer vs float64 oracle", "rasterizer gradients"):
            assert r["worst_error"] < 1e-4, r
        elif r["group"] != "avatar training loop":  # rotations, FK + LBS
            assert r["worst_error"] < (1e-12 if r["method"].endswith("float64") else 1e-4), r
    assert [r["case"] for r in rows if r["group"] == "avatar training loop"] == \
        ["learning rates x1 (0.001)", "learning rates x100 (0.1)"]
    md = (out / "stability.md").read_text()
    assert "| 1e4 m scene from 1e4 times farther | numpy float32 |" in md and "Every output finite: yes." in md
    assert f"bench: report {out / 'stability.md'}" in capsys.readouterr().out
