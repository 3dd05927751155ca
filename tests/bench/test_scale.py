"""``trioman bench scale`` at a tiny size: 1 and 2 processes, the communication share, the prediction (recomputed)."""

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
    p, c, (one, two) = r["prediction"], r["communication"], r["runs"]
    assert p["gpus"] == 8 and len(p["assumes"]) == 4
    assert c["exposed_s"] == pytest.approx(max(0.0, two["step_s"] - c["no_sync_step_s"]))
    ring = (2 * 7 / 8) / (2 * 1 / 2)  # a ring all-reduce sends 2 (n - 1) / n of the gradients: 8 GPUs against 2
    for name, t_comm in (("allreduce", c["allreduce_s"]), ("exposed", c["exposed_s"])):
        t8 = one["step_s"] + ring * t_comm  # each GPU computes as one process does alone, then communicates
        assert p[name]["step_s"] == pytest.approx(t8), name
        assert p[name]["samples_per_s"] == pytest.approx(8 * 1 / t8) and p[name]["efficiency"] == pytest.approx(one["step_s"] / t8)
    md = (out / "scale.md").read_text()
    assert "| 2 | 2 |" in md and "Prediction for 8 GPUs" in md
    assert f"bench: report {out / 'scale.md'}" in capsys.readouterr().out
