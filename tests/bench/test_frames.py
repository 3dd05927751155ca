"""``trioman bench frames`` at a tiny size: the stages and the report."""

import json

import pytest

pytest.importorskip("torch")

from trioman.cli import main  # noqa: E402


def test_bench_frames_reports_each_stage(tmp_path, capsys):
    out = tmp_path / "bench"
    assert main(["bench", "frames", "--out", str(out), "--frames", "3", "--size", "32", "--iterations", "1"]) == 0
    report = json.loads((out / "frames.json").read_text())
    assert (report["frames"], report["size"], report["iterations"]) == (3, 32, 1)
    assert set(report["stages"]) == {"write subject", "train"} and report["process_peak_rss_mib"] > 0
    assert "| train |" in (out / "frames.md").read_text()
    assert f"bench: report {out / 'frames.md'}" in capsys.readouterr().out
