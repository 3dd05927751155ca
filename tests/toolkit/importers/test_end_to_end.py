"""import (X-Humans layout, fake SMPL-X) -> train a few iterations -> eval -> export avatar -> animate."""

from __future__ import annotations

import json

import pytest

pytest.importorskip("torch")
pytest.importorskip("anny")
pytest.importorskip("smplx", reason="needs the 'smplx' extra: pip install 'trioman[smplx]'")

from trioman.cli import main  # noqa: E402
from trioman.runtime.formats import load_avatar  # noqa: E402
from tests.toolkit.importers import layouts  # noqa: E402


def test_import_train_eval_export_animate(tmp_path, smplx_model_dir, capsys):
    layouts.write_xhumans(tmp_path / "data", smplx_model_dir)
    subject, run, avatar = tmp_path / "subject", tmp_path / "run", tmp_path / "avatar"
    steps = [
        ["import", "exavatar", str(tmp_path / "data"), "--dataset", "xhumans", "--subject", "00028", "--out",
         str(subject), "--body-model-dir", str(smplx_model_dir), "--allow-pickle"],
        ["train", str(subject), "--out", str(run), "--iterations", "3", "--quiet"],
        ["eval", str(run), "--quiet", "--no-video", "--protocol", "exavatar"],
        ["export", "avatar", str(run), "--out", str(avatar)],
        ["animate", str(avatar), "--motion", str(subject), "--out", str(tmp_path / "test.mp4"), "--size", "64", "--quiet"],
    ]
    for argv in steps:
        assert main(argv) == 0, f"trioman {' '.join(argv[:2])}: {capsys.readouterr().err}"
    summary = json.loads((run / "eval_test" / "summary.json").read_text())
    assert summary["frames"] == 2
    e = summary["exavatar"]  # ExAvatar's protocol beside ours: the same masked composite, both SSIM borders
    assert e["psnr"] == summary["mean"]["psnr"] and e["ssim"] == summary["mean"]["ssim"] and 0 < e["ssim_tm14"] <= 1
    assert "ExAvatar's protocol" in (run / "eval_test" / "report.md").read_text()
    loaded = load_avatar(avatar)
    assert loaded.meta["body_model"] == "smplx" and loaded.skeleton.num_joints == 55
    assert (tmp_path / "test.mp4").stat().st_size > 0
