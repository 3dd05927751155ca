"""``trioman bench scale`` at a tiny size: 1 and 2 processes, the communication share, the prediction."""

import json

import pytest

pytest.importorskip("torch")

from trioman.cli import main  # noqa: E402


def test_bench_scale_reports_throughput_communication_and_a_prediction(tmp_path, capsys):
    out = tmp_path / "bench"
    assert main(["bench", "scale", "--out", str(out), "--size", "16", "--batch", "1", "--iterations", "2"]) == 0
    r = json.loads((out / "scale.json").read_text())
    assert [row["processes"] for row in r["runs"]] == [1, 2] and [row["global_batch"] for row in r["runs"]] == [1, 2]
    assert all(row["samples_per_s"] > 0 for row in r["runs"])
    assert 0 < r["communication"]["allreduce_share"] and 0 <= r["communication"]["exposed_share"] < 1
    p = r["prediction"]
    assert p["gpus"] == 8 and p["exposed"]["samples_per_s"] > 0 and p["allreduce"]["samples_per_s"] > 0 and len(p["assumes"]) == 4
    md = (out / "scale.md").read_text()
    assert "| 2 | 2 |" in md and "Prediction for 8 GPUs" in md
    assert f"bench: report {out / 'scale.md'}" in capsys.readouterr().out
