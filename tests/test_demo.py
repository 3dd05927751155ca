"""The demo end to end at a tiny size (64 px), in `make test` so a broken demo cannot pass CI."""

import json
import math
import re

import pytest

pytest.importorskip("torch")
pytest.importorskip("anny")

from trioman.cli import main  # noqa: E402
from trioman.runtime.formats import load_avatar, load_subject  # noqa: E402
from trioman.runtime.image_io import read_png  # noqa: E402

STAGES = ("synth", "turntable", "train", "eval test", "eval train", "export avatar", "animate", "augment",
          "train augmented", "eval augmented", "novel views")
STAGE_LINE = re.compile(r"^demo: stage (.+?) +(\d+\.\d) s +peak RSS +(\d+) MiB(?: \(since start\))?$", re.M)
PSNR_LINE = re.compile(r"^demo: test PSNR \(masked\): baseline (\S+) dB, augmented (\S+) dB \(\S+ dB, the same (\d+) "
                       r"steps\); report (\S+)$", re.M)


def test_demo_runs_export_augment_and_the_augmented_avatar_with_the_shipped_models(tmp_path, capsys):
    from trioman.runtime.pretrained import shipped_path

    out = tmp_path / "demo"
    argv = ["demo", "--out", str(out), "--size", "64", "--frames", "12", "--iterations", "30",
            "--augment-frames", "2", "--quiet"]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    stages = STAGE_LINE.findall(printed)
    assert tuple(name for name, _, _ in stages) == STAGES
    assert all(float(seconds) >= 0 and int(mib) > 0 for _, seconds, mib in stages)
    overall = re.search(r"^demo: done in \d+ s; peak RSS (\d+) MiB", printed, re.M)
    assert overall and int(overall.group(1)) == max(int(mib) for _, _, mib in stages)

    assert f"pseudo-GT     {out / 'augmented'}" in printed
    load_avatar(out / "avatar")
    result = json.loads((out / "augmented" / "augment.json").read_text())
    assert result["settings"]["refiner"]["path"] == str(shipped_path("refiner"))
    assert result["settings"]["examiner"]["path"] == str(shipped_path("examiner"))
    assert result["summary"]["source_frames"] == 2 and result["summary"]["accepted"] == 2
    assert load_subject(out / "augmented").num_frames == 2
    assert (out / "animate_walk.mp4").stat().st_size > 0

    run_aug = out / "run_augmented"
    train_cfg = json.loads((run_aug / "config.json").read_text())["train"]
    assert train_cfg["augment"]["mode"] == "aligned" and train_cfg["iterations"] == 30  # what --augment alone runs
    assert f"(trioman train {out / 'subject'} --augment: aligned pseudo-GT)" in printed
    psnr = PSNR_LINE.search(printed)
    assert psnr and psnr.group(4) == str(run_aug / "eval_test" / "report.md") and psnr.group(3) == "30"
    baseline, augmented = float(psnr.group(1)), float(psnr.group(2))
    assert math.isfinite(baseline) and math.isfinite(augmented)
    for run, value in ((out / "run", baseline), (run_aug, augmented)):
        summary = json.loads((run / "eval_test" / "summary.json").read_text())
        assert summary["split"] == "test" and round(summary["mean"]["psnr"], 2) == value
    assert f"novel views   {out / 'novel_views.png'}" in printed
    grid = read_png(out / "novel_views.png")  # a row per test frame: GT | baseline | augmented, 64 px each
    assert grid.shape[1] > 3 * 64 and grid.shape[0] > 4 * 64
    assert load_subject(out / "subject").meta["generator"]["coverage"] == 0.33  # the regime the gain was measured in

    # issue 41: a rerun starts its runs afresh, removing the demo's own and nothing else
    from trioman.runtime.outputs import check_folder_target
    from trioman.toolkit.train.loop import RUN_FOLDER

    for folder, kind in (("run", RUN_FOLDER), ("run_augmented", RUN_FOLDER)):
        check_folder_target(out / folder, True, kind)  # what a rerun removes: the demo's own output, whole
    (out / "run" / "notes.txt").write_text("mine")
    capsys.readouterr()
    assert main(argv) == 1
    assert f"{out / 'run' / 'notes.txt'} was not written by trioman" in capsys.readouterr().err
    assert (out / "run" / "notes.txt").read_text() == "mine" and (out / "run" / "config.json").is_file()
