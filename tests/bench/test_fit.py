"""``trioman bench fit`` end to end at a tiny size."""

import pytest

from tests.conftest import skip_without_person_models

pytest.importorskip("torch")
pytest.importorskip("anny")

from trioman.bench.fit import FitBenchConfig, bench_fit, fit_markdown  # noqa: E402

skip_without_person_models()


def test_bench_fit_compares_a_fit_with_its_truth(tmp_path, capsys):
    r = bench_fit(FitBenchConfig(out=tmp_path, subjects=1, size=256, frames=14, iterations=20, focal="truth", avatar_iterations=10))
    (row,) = r["rows"]
    assert row["frames_read"] == 10 and 2 <= row["frames_kept"] <= 10
    assert 0 < row["pa_mpjpe"] < 300 and 0 < row["mask_iou"] <= 1 and row["seconds"] > 0
    md = fit_markdown(r)
    assert "| s1004 |" in md and "PA-MPJPE <= 40.0 mm" in md and "cost of fitting" in md
    assert row["cost_of_fitting_db"] == round(row["psnr_true_poses"] - row["psnr_fitted_poses"], 2)
    assert row["cost_refined_db"] == round(row["psnr_true_poses"] - row["psnr_refined_poses"], 2)
    assert row["cost_of_the_frames_db"] == round(row["psnr_true_poses"] - row["psnr_true_poses_video_frames"], 2)
    assert "fitted, refined" in md and "the video's frames and masks" in md
    # and the field's protocol: the test poses refitted to their pixels, both arms the same way
    for arm in ("fitted", "refined"):
        assert row[f"cost_{arm}_refitted_db"] == round(row["psnr_true_refitted"] - row[f"psnr_{arm}_refitted"], 2)
        assert row[f"cost_{arm}_refitted_same_frames_db"] == round(
            row["psnr_true_video_refitted"] - row[f"psnr_{arm}_refitted"], 2)
    worst = max(row[k] for k in row if k.startswith("cost_") and "_refitted" in k)
    assert f"{'met' if worst <= 1.0 else 'MISSED'} (worst {worst})" in md
    assert "refitted to each held-out frame's pixels" in md and f"| {row['psnr_fitted_refitted']} |" in md
    assert (tmp_path / "fit_work" / "s1004_avatar_true" / "eval_test_optimised").is_dir()
    # the twin of the video's frames holds the fitted subject's own pixels at the truth's poses and cameras
    from trioman.runtime.formats import load_subject

    fitted, twin = load_subject(tmp_path / "fit_work" / "s1004_fit"), load_subject(tmp_path / "fit_work" / "s1004_true_poses_video_frames")
    truth = load_subject(tmp_path / "fit_work" / "s1004")
    assert list(twin.frame_names) == list(fitted.frame_names)
    assert (twin.image(0) == fitted.image(0)).all() and (twin.mask(0) == fitted.mask(0)).all()
    assert (twin.K[0] == truth.K[list(truth.frame_names).index(twin.frame_names[0])]).all()
    # one line per step: a logged run is not silent
    lines = [line for line in capsys.readouterr().out.splitlines() if line.startswith("bench fit: s1004: ")]
    assert len(lines) == 2 + 4 and "fitted (" in lines[1] and lines[-1].startswith("bench fit: s1004: avatar on the true poses and the video's frames")


def test_bench_fit_fits_a_capture_of_a_few_steps(tmp_path):
    r = bench_fit(FitBenchConfig(out=tmp_path, subjects=1, size=192, frames=14, iterations=20, capture="steps", coverage=0.5))
    (row,) = r["rows"]
    assert row["frames_kept"] >= 2 and 0 < row["pa_mpjpe"] < 300
    from trioman.runtime.formats import load_subject

    made = load_subject(tmp_path / "fit_work" / "s1004").meta["generator"]
    assert made["capture"] == "steps" and made["coverage"] == 0.5
    assert "capture: steps, coverage 0.5" in fit_markdown(r) and "--capture steps --coverage 0.5" in fit_markdown(r)


@pytest.mark.parametrize("kwargs, field", [(dict(focal="guess"), "focal"), (dict(subjects=0), "subjects"),
                                            (dict(style="cartoon"), "style"), (dict(capture="jog"), "capture")])
def test_bad_bench_settings_are_named(kwargs, field):
    with pytest.raises(ValueError, match=f"^{field}: "):
        FitBenchConfig(**kwargs)
