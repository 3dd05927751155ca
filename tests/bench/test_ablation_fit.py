"""``trioman bench ablation --poses fit`` end to end at a tiny size: the held-out subject re-rendered as a video of
every frame, fitted, linked to its truth; the control trains on the fitted poses, the ceiling on the truth at the
draws (the truth through the link: tests/toolkit/synth/test_linked.py), and the report gives the fit's error."""

import json

import pytest

from tests.conftest import skip_without_person_models

pytest.importorskip("torch")
pytest.importorskip("anny")

from trioman.bench.ablation import AblationPlan, regime_subject  # noqa: E402
from trioman.cli import main  # noqa: E402
from trioman.runtime.formats import load_subject  # noqa: E402
from trioman.toolkit.corpus.build import CorpusConfig, build_corpus  # noqa: E402
from trioman.toolkit.fit.config import FitConfig  # noqa: E402

skip_without_person_models()


def test_the_ablation_on_fitted_poses(tmp_path, capsys):
    corpus = tmp_path / "c"
    build_corpus(corpus, CorpusConfig(train_subjects=1, heldout_subjects=1, size=128, frames=16, iterations=2,
                                      style="realistic"), progress=False)
    heldout = json.loads((corpus / "corpus.json").read_text())["subjects"][-1]["name"]
    out = tmp_path / "bench"
    plan = AblationPlan(coverage=0.5, poses="fit", video_side=256)
    fitted = regime_subject(corpus / "subjects" / heldout, out, plan, fit=FitConfig(keyframes=6, key_iterations=30, all_iterations=20))
    linked, truth = load_subject(fitted), load_subject(fitted.with_name(fitted.name + "_truth"))
    assert fitted.name == f"{heldout}-cov0.5-fit256" and linked.meta["generator"]["tool"] == "trioman fit"
    report = json.loads((fitted.with_name(fitted.name + "_fit") / "fit.json").read_text())
    assert report["track_size"] == [256, 256] and report["size"] == [128, 128] == [linked.width, linked.height]
    assert linked.K[0, 0, 2] == pytest.approx(64.0, abs=8.0)  # the camera at the subject's size, not the video's
    assert set(linked.split) == {"train", "test"} and set(linked.sequence) <= set(truth.sequence)
    assert linked.num_frames >= 0.75 * truth.num_frames  # the fit kept most frames (the video holds them all)
    assert main(["bench", "ablation", "--corpus", str(corpus), "--out", str(out), "--poses", "fit", "--coverage", "0.5",
                 "--video-side", "256", "--iterations", "4", "--seeds", "1", "--variants", "baseline_long,ceiling",
                 "--refiner-steps", "2", "--examiner-steps", "2", "--batch", "2", "--augment-refresh", "2",
                 "--augment-pool", "2"]) == 0
    report = json.loads((out / "ablation.json").read_text())
    name = f"{heldout}-cov0.5-fit256"
    assert set(report["results"][name]) == {"baseline_long", "ceiling"}
    assert report["results"][name]["ceiling"]["0"]["augment"]["pseudo_steps"] > 0  # the truth at fitted draws, through the link
    summary_file = out / "runs" / name / "ceiling_s0" / "eval_test" / "summary.json"
    summary = json.loads(summary_file.read_text())
    assert "refitted to each frame" in summary["poses"]  # the fitted test poses refitted to their pixels, the avatar frozen
    written = summary_file.stat().st_mtime_ns
    assert main(["bench", "ablation", "--corpus", str(corpus), "--out", str(out), "--poses", "fit", "--coverage", "0.5",
                 "--video-side", "256", "--iterations", "4", "--seeds", "1", "--no-training"]) == 0
    assert summary_file.stat().st_mtime_ns == written  # a run evaluated at its refitted poses is reused, not refitted again
    summary_file.write_text(json.dumps({**summary, "poses_key": "optimised"}))  # as an earlier refit recorded it
    assert main(["bench", "ablation", "--corpus", str(corpus), "--out", str(out), "--poses", "fit", "--coverage", "0.5",
                 "--video-side", "256", "--iterations", "4", "--seeds", "1", "--no-training"]) == 0
    assert json.loads(summary_file.read_text())["poses_key"].startswith("optimised (L-BFGS")  # another refit: evaluated again
    fit = report["fit"][name]
    assert fit["frames"] == linked.num_frames and 0 < fit["pa_mpjpe"] < 500 and fit["pa_mpjpe_test"] > 0
    assert "## The fitted poses against the truth" in (out / "ablation.md").read_text()
    capsys.readouterr()
    assert main(["bench", "ablation", "--corpus", str(corpus), "--out", str(out), "--poses", "fit", "--pose-noise", "2"]) == 1
    assert "--pose-noise: the fitted poses carry the fit's own error" in capsys.readouterr().err
