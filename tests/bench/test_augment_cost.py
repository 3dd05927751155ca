"""``trioman bench augment-cost`` at a tiny size: both runs, their ratio and the augmentation's stage times."""

import json

import pytest

pytest.importorskip("torch")
pytest.importorskip("anny")

from trioman.cli import main  # noqa: E402


def test_bench_augment_cost_times_the_plain_and_the_default_augmented_run(tmp_path, capsys):
    out = tmp_path / "bench"
    assert main(["bench", "augment-cost", "--out", str(out), "--size", "32", "--frames", "8", "--iterations", "20"]) == 0
    report = json.loads((out / "augment-cost.json").read_text())
    (row,) = report["rows"]
    assert row["size"] == 32 and row["plain_s"] > 0 and row["augmented_s"] > 0
    assert row["ratio"] == pytest.approx(row["augmented_s"] / row["plain_s"], rel=0.005)  # seconds kept to 0.01 s
    assert row["target_met"] == (row["ratio"] <= report["target_ratio"])
    assert report["augment"]["mode"] == "aligned" and report["augment"]["pool"] == 32  # what --augment alone runs
    assert row["pseudo_steps"] > 0 and row["augment_seconds"]["render"] > 0  # pseudo frames were made and trained on
    for name in ("plain", "augmented"):
        cfg = json.loads((out / "augment_cost" / f"run_32_{name}" / "config.json").read_text())["train"]
        assert cfg["iterations"] == 20 and (cfg["augment"] is None) == (name == "plain")
    assert "| 32 |" in (out / "augment-cost.md").read_text()
    assert f"bench: report {out / 'augment-cost.md'}" in capsys.readouterr().out
