"""``trioman bench ablation`` end to end at a tiny size: every variant trains, the report, plots and
grids are written, and a rerun reuses the finished runs."""

import json

import numpy as np
import pytest

pytest.importorskip("torch")
pytest.importorskip("anny")

from trioman.cli import main  # noqa: E402
from trioman.bench.ablation import LABELS, ablation_markdown, summarise  # noqa: E402
from trioman.bench.ablation.measure import FUSED_TEXTURE  # noqa: E402
from trioman.bench.ablation.report import _frame_target  # noqa: E402
from trioman.bench.ablation_config import LEVERS, VARIANTS, AblationPlan  # noqa: E402
from trioman.toolkit.corpus.build import CorpusConfig, build_corpus  # noqa: E402


@pytest.fixture(scope="module")
def corpus(tmp_path_factory):
    root = tmp_path_factory.mktemp("corpus") / "c"
    return build_corpus(root, CorpusConfig(train_subjects=2, heldout_subjects=1, size=32, frames=8, iterations=2), progress=False)


def test_ablation_writes_tables_figures_and_resumes(corpus, tmp_path, capsys):
    out = tmp_path / "bench"
    argv = ["bench", "ablation", "--corpus", str(corpus), "--out", str(out), "--size", "32", "--iterations", "3",
            "--seeds", "2", "--refiner-steps", "2", "--examiner-steps", "2", "--batch", "2", "--crop", "16", "--detail-sigma", "2"]
    assert main(argv) == 0
    r = json.loads((out / "ablation.json").read_text())
    res = r["results"]["s02"]
    assert list(res) == [v for v, *_ in VARIANTS + LEVERS]
    assert set(res["baseline"]) == set(res["GRE"]) == {"0", "1"} and set(res["G"]) == {"0"}
    plan = AblationPlan(iterations=3)
    assert res["baseline"]["0"]["iterations"] == 3 and res["GRE"]["0"]["iterations"] == plan.augmented_iterations == 5  # 3 / (0.2 + 0.8 * 0.5)
    assert res["baseline_long"]["0"]["iterations"] == 5 and res["baseline"]["0"]["augment"] is None
    assert r["plan"]["detail_sigma"] == 2.0
    truth = r["pseudo_gt_truth"]["s02"]
    assert set(truth["frames"]) == {"coarse", "aligned (no Refiner)", "aligned, fused texture 256 (no Refiner)",
                                    "refined (none)", "refined (tex)", "refined (tex+geo)",
                                    "refined (warp+geo)", "refined (warp+geo), carried pixels kept",
                                    "refined (warp+geo), carried pixels kept, fused texture 256",
                                    "detail only (tex+geo, 2 px)"}
    assert all(np.isfinite(v) for v in truth["frames"].values()) and 0 < truth["coverage"]["aligned (no Refiner)"] <= 1
    check_frame_level_numbers(out / "pseudo_gt_s02.npz", truth)
    assert truth["coverage"]["aligned (no Refiner)"] <= truth["coverage"]["aligned, fused texture 256 (no Refiner)"] <= 1
    assert set(truth["avatars"]) == {v for v, *_ in VARIANTS + LEVERS} and all(
        np.isfinite(a["psnr"]) and len(a["colour_bias"]) == 3 for a in truth["avatars"].values())
    e = truth["examiner"]
    assert e["pairs"] == 12 and 0 <= e["agreement"] <= 1 and all(np.isfinite(v) for v in e.values())
    cfg = json.loads((out / "runs" / "s02" / "GRd_tex_geo_s0" / "config.json").read_text())
    assert cfg["train"]["augment"]["detail_sigma"] == 2.0
    cfg = json.loads((out / "runs" / "s02" / "GRk_warp_geo_s0" / "config.json").read_text())["train"]["augment"]
    assert cfg["keep_carried"] and cfg["refiner"].endswith("refiner_warp_geo")
    assert json.loads((out / "runs" / "s02" / "GRE_s0" / "config.json").read_text())["train"]["augment"]["keep_carried"]
    for variant, mode in (("G", "coarse"), ("aligned", "aligned"), ("GR_tex", "refined"), ("GR_warp+geo", "refined"),
                          ("GRk_warp+geo", "refined"), ("GRE", "examined"),
                          ("GRd_tex+geo", "refined"), ("ceiling_seen", "truth_seen"), ("ceiling", "truth")):
        a = res[variant]["0"]["augment"]
        assert a["mode"] == mode and a["entries"] > 0 and a["kept"] <= a["entries"], variant  # entries made when drawn
        assert (a["kept"] > 0) == (a["pseudo_steps"] > 0), variant
    assert all(np.isfinite(x["psnr"]) for runs in res.values() for x in runs.values())
    assert set(r["condition_check"]["tex+geo"]) == {"coarse", "true", "without_reference", "zero_normal"}
    assert set(r["condition_check"]["warp+geo"]) == {"coarse", "aligned", "true", "without_reference", "zero_normal"}
    assert all(np.isfinite(x) for c in r["condition_check"].values() for x in c.values())
    assert json.loads((out / "runs" / "s02" / "GRE_s0" / "config.json").read_text())["train"]["augment"]["refiner"].endswith(
        "refiner_warp_geo")
    md = (out / "ablation.md").read_text()
    # the report's numbers are the summary's
    mean = r["summary"]["mean"]
    for v in ("baseline", "ceiling", "ceiling_seen", "aligned"):
        assert f"| {LABELS[v]} | {mean[v]['psnr']:.2f} |" in md, v
    assert all(np.isfinite(mean[v]["psnr"]) for v in mean)
    for text in ("Table 1", "Table 2", "+ Generator & Refiner (aligned ref.&geo., carried pixels kept) & Examiner", "equal steps (control)", "paper 00028",
                 "Ceiling (the truth at every draw) over the equal-steps control", "share of the ceiling's gain",
                 "Do the Refiners use their conditions", "| refined, true reference and normal map |", "ms per step",
                 "detail only (lever)", "Pseudo-GT against the truth: s02", "What the Examiner keeps",
                 "Frame-level target: refined (warp+geo, carried pixels kept)", "Frame-level target with the fused texture 256"):
        assert text in md, text
    for name in ("ablation_s02.png", "grid_s02.png", "pseudo_gt_s02.png"):
        assert (out / name).stat().st_size > 0, name
    first = (out / "runs" / "s02" / "GRE_s1" / "checkpoints").iterdir().__next__().stat().st_mtime_ns
    assert main(argv) == 0  # finished runs are reused, not retrained
    assert (out / "runs" / "s02" / "GRE_s1" / "checkpoints").iterdir().__next__().stat().st_mtime_ns == first
    import shutil

    shutil.rmtree(out / "runs" / "s02" / "GR_none_s0")
    assert main(argv + ["--no-training"]) == 0  # a report of the finished runs; the removed one is named, not retrained
    assert not (out / "runs" / "s02" / "GR_none_s0").exists()
    r2 = json.loads((out / "ablation.json").read_text())
    assert r2["missing_runs"] == ["s02/GR_none_s0"] and "GR_none" not in r2["results"]["s02"]
    assert "not yet trained: s02/GR_none_s0" in (out / "ablation.md").read_text()
    assert main(argv[:-2] + ["--ablation-subjects", "s00"]) == 1
    assert "--ablation-subjects: ['s00'] are not held-out subjects" in capsys.readouterr().err
    assert r["baseline_frames"] == "all" and "coarse frames of the 'all' variant" in md
    assert main(argv + ["--baseline-frames", "all,subset"]) == 1
    assert "--baseline-frames: ablation trains on one corpus variant" in capsys.readouterr().err

    # another capture regime: the held-out subject re-rendered (half a turn, 3 degrees of pose noise), only some rows
    regime = ["--coverage", "0.5", "--pose-noise", "3", "--variants", "ceiling"]
    assert main(argv + regime) == 0
    r3 = json.loads((out / "ablation.json").read_text())
    name = "s02-cov0.5-noise3"
    assert r3["subjects"] == [name] and set(r3["results"][name]) == {"ceiling"} and name not in r3["pseudo_gt_truth"]
    assert "s02-cov0.5-noise3/GRE_s0" in r3["missing_runs"] and r3["plan"]["coverage"] == 0.5
    from trioman.runtime.formats import load_subject

    subj = load_subject(out / "subjects" / name)
    assert subj.meta["generator"]["coverage"] == 0.5 and subj.meta["generator"]["pose_noise_deg"] == 3.0
    summary = json.loads((out / "runs" / name / "ceiling_s0" / "eval_test" / "summary.json").read_text())
    assert summary["poses"] == "true"  # with pose noise the avatars are scored at the true test poses
    assert "0.5 of a full turn" in (out / "ablation.md").read_text()
    # the Generator's reach: augmented runs get their own folders, unaugmented ones are the capture regime's
    assert main(argv + regime[:4] + ["--reach", "2", "--variants", "baseline,ceiling"]) == 0
    r4 = json.loads((out / "ablation.json").read_text())
    far = name + "-reach2"
    assert r4["subjects"] == [far] and set(r4["results"][far]) == {"baseline", "ceiling"} and r4["plan"]["reach"] == 2
    assert (out / "runs" / name / "baseline_s0").is_dir() and not (out / "runs" / far / "baseline_s0").exists()
    camera = json.loads((out / "runs" / far / "ceiling_s0" / "config.json").read_text())["train"]["augment"]["camera"]
    assert camera == pytest.approx([1.0, 0.3, 0.2])
    assert far in r4["pseudo_gt_truth"] and "camera sigmas x2" in (out / "ablation.md").read_text()
    assert main(argv + ["--reach", "0"]) == 1
    assert "--reach: the Generator's camera sigmas" in capsys.readouterr().err
    assert main(argv + ["--variants", "baseline,magic"]) == 1
    assert "--variants: unknown ['magic']" in capsys.readouterr().err


def check_frame_level_numbers(saved, truth: dict) -> None:
    """The frame-level table against the frames it scored (pseudo_gt_<name>.npz): each kind's masked PSNR recomputed
    with runtime.metrics; and what the kinds are by definition, pixel by pixel: the aligned frame is the render but
    where real pixels were carried, and the frame with the carried pixels kept is the aligned one there and the
    warp+geo Refiner's frame elsewhere (with the fused texture: the fused aligned frame there)."""
    from trioman.runtime.metrics import psnr

    with np.load(saved) as z:
        labels, frames, true, mask = z["labels"].tolist(), z["frames"], z["truth"], z["mask"][..., None]
    assert labels == list(truth["frames"]) and frames.shape[:2] == (len(labels), truth["draws"]) and true.shape == frames.shape[1:]
    for label, images in zip(labels, frames):
        assert float(psnr((images * mask)[None], (true * mask)[None])[0]) == pytest.approx(truth["frames"][label], abs=1e-4), label
    frame = dict(zip(labels, frames))
    coarse, kept = frame["coarse"], frame["refined (warp+geo), carried pixels kept"]
    carried = (frame["aligned (no Refiner)"] != coarse).any(-1)
    body = mask[..., 0] > 0.5
    assert (carried & body).any() and (~carried & body).any()  # real pixels reached some of the body, not all of it
    np.testing.assert_array_equal(kept[carried], frame["aligned (no Refiner)"][carried])
    np.testing.assert_array_equal(kept[~carried], frame["refined (warp+geo)"][~carried])
    fused = frame[f"aligned, fused texture {FUSED_TEXTURE} (no Refiner)"]
    carried = (fused != coarse).any(-1)
    assert carried.any()
    np.testing.assert_array_equal(frame[f"refined (warp+geo), carried pixels kept, fused texture {FUSED_TEXTURE}"][carried],
                                  fused[carried])


def test_a_row_alone_trains_only_the_models_it_needs(corpus, tmp_path):
    """--variants: the rows' Refiners train, no other; the Examiner only for GRE; the condition check covers the
    Refiners there."""
    from trioman.bench.ablation import needed_models

    assert needed_models(["GR_tex"]) == ["refiner_tex"]
    assert needed_models(["GRE", "baseline"]) == ["refiner_warp+geo", "examiner"]
    assert needed_models([v for v, *_ in VARIANTS]) == ["refiner_none", "refiner_tex", "refiner_tex+geo", "refiner_warp+geo", "examiner"]
    out = tmp_path / "bench"
    argv = ["bench", "ablation", "--corpus", str(corpus), "--out", str(out), "--size", "32", "--iterations", "2",
            "--seeds", "1", "--refiner-steps", "2", "--batch", "2", "--crop", "16", "--variants", "baseline,GR_tex+geo"]
    assert main(argv) == 0
    assert sorted(p.name for p in (out / "models").iterdir()) == ["refiner_tex_geo"]
    r = json.loads((out / "ablation.json").read_text())
    assert set(r["results"]["s02"]) == {"baseline", "GR_tex+geo"} and set(r["condition_check"]) == {"tex+geo"}


def test_jobs_train_the_runs_in_worker_processes(corpus, tmp_path, capsys):
    """--jobs 2: the rows train in two spawned processes, then evaluate as when trained in this one."""
    out = tmp_path / "bench"
    argv = ["bench", "ablation", "--corpus", str(corpus), "--out", str(out), "--size", "32", "--iterations", "2",
            "--seeds", "1", "--refiner-steps", "2", "--batch", "2", "--crop", "16", "--variants", "baseline,baseline_long,G", "--jobs", "2"]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert printed.count("bench ablation: trained s02/") == 3 and "2 jobs x" in printed
    # the control and G share the control's first steps: trained once, then forked (toolkit/train/fork.py)
    assert printed.count("bench ablation: warmed up s02/warmup_s0_") == 1
    for v in ("baseline_long_s0", "G_s0"):
        assert json.loads((out / "runs" / "s02" / v / "config.json").read_text())["forked_from"]["step"] == 1
    assert "forked_from" not in json.loads((out / "runs" / "s02" / "baseline_s0" / "config.json").read_text())
    r = json.loads((out / "ablation.json").read_text())
    assert set(r["results"]["s02"]) == {"baseline", "baseline_long", "G"}
    assert r["results"]["s02"]["G"]["0"]["augment"]["mode"] == "coarse" and r["results"]["s02"]["G"]["0"]["iterations"] == 3


def test_a_failed_worker_run_is_named(tmp_path):
    from trioman.bench.ablation import Job, train_in_parallel
    from trioman.toolkit.train.config import preset

    with pytest.raises(RuntimeError, match="run .*missing_run failed"):
        train_in_parallel([Job(tmp_path / "no_subject", tmp_path / "missing_run", preset("quick", iterations=1))], 2, False)


def test_summary_verdicts_follow_the_numbers():
    def runs(*psnrs):
        return {str(i): {"psnr": p, "ssim": 0.9, "lpips": None, "psnr_unmasked": p, "ssim_unmasked": 0.9}
                for i, p in enumerate(psnrs)}

    res = {"a": {"baseline": runs(20.0, 20.2), "baseline_long": runs(20.1), "G": runs(20.5), "GR_none": runs(20.4),
                 "GR_tex": runs(20.9), "GR_tex+geo": runs(21.0), "GRE": runs(21.3, 21.5)}}
    s = summarise(res)
    v = s["verdict"]
    assert v["full_gain_db"] == pytest.approx(1.3) and v["full_gain_at_least_1db"] and v["gain_exceeds_twice_seed_spread"]
    assert v["table1_order_holds"] and v["table2_order_holds"]
    assert s["seed_spread_psnr"]["baseline"] == pytest.approx(0.2) and s["mean"]["GRE"]["lpips"] is None
    res["a"]["GR_none"] = runs(21.2)
    assert not summarise(res)["verdict"]["table2_order_holds"]
    one = {"a": {**res["a"], "GRE": runs(21.3)}}  # GRE with one seed: only the baseline's spread counts
    assert summarise(one)["seed_spread_psnr"] == {"baseline": pytest.approx(0.2)}
    one["a"]["baseline"] = runs(20.0)  # no run with two seeds: no spread, no verdict on it
    assert summarise(one)["seed_spread_psnr"] == {} and "gain_exceeds_twice_seed_spread" not in summarise(one)["verdict"]
    assert "control_gain_exceeds_twice_seed_spread" not in summarise(res)["verdict"]  # the control has one seed
    two = {"a": {**res["a"], "baseline_long": runs(20.1, 20.5)}}  # gain over the control 1.0, its spread 0.4
    v = summarise(two)["verdict"]
    assert v["control_gain_db"] == pytest.approx(21.4 - 20.3) and v["control_gain_exceeds_twice_seed_spread"]
    two["a"]["baseline_long"] = runs(20.1, 20.8)
    assert not summarise(two)["verdict"]["control_gain_exceeds_twice_seed_spread"]  # 0.95 < 2 x 0.7
    # against the ceiling: shares of its gain over the equal-steps control, the unmasked check
    res["a"]["ceiling"] = runs(22.1)
    s = summarise(res)
    assert s["share_of_ceiling"]["GRE"] == pytest.approx((21.4 - 20.1) / 2.0)
    assert s["share_of_ceiling"]["G"] == pytest.approx(0.2) and "baseline" not in s["share_of_ceiling"]
    v = s["verdict"]
    assert v["ceiling_gain_db"] == pytest.approx(2.0) and v["ceiling_gain_at_least_1db"] and not v["full_recovers_85_percent"]
    assert v["unmasked_at_least_baseline"]["G"] and v["unmasked_at_least_baseline"]["ceiling"]
    assert "full_share_of_seen_ceiling" not in v  # no seen-surface ceiling run
    res["a"]["ceiling_seen"] = runs(21.7)
    v = summarise(res)["verdict"]
    assert v["seen_share_of_ceiling"] == pytest.approx(0.8) and v["full_share_of_seen_ceiling"] == pytest.approx(1.3 / 1.6)
    assert "of that seen-surface ceiling's gain" in ablation_markdown(
        {"plan": {**AblationPlan().record(), "augmented_iterations": 10}, "subjects": ["a"], "corpus": "c", "lpips": False,
         "summary": summarise(res), "results": {}, "condition_check": {}, "pseudo_gt_truth": {}, "models": {}, "wall_seconds": 1.0})
    res["a"]["GR_warp+geo"] = runs(21.2)
    assert summarise(res)["verdict"]["warp_order_holds"]
    res["a"]["GR_warp+geo"] = runs(21.5)  # above the full system
    assert not summarise(res)["verdict"]["warp_order_holds"]
    res["a"]["G"] = {"0": {**runs(20.5)["0"], "psnr_unmasked": 19.0}}
    assert not summarise(res)["verdict"]["unmasked_at_least_baseline"]["G"]



def test_the_frame_level_target_reads_each_kind_and_says_which_holds():
    frames = {"coarse": 28.0, "aligned (no Refiner)": 29.4, "refined (warp+geo), carried pixels kept": 29.6,
              "aligned, fused texture 256 (no Refiner)": 30.0, "refined (warp+geo), carried pixels kept, fused texture 256": 30.1}
    plain, fused = _frame_target(frames)
    assert plain.endswith("render + 1.5 dB (29.50): does not hold.") and "29.60 >= aligned 29.40" in plain
    assert fused.startswith("Frame-level target with the fused texture 256") and fused.endswith(": holds.")
    frames["refined (warp+geo), carried pixels kept, fused texture 256"] = 29.9  # below its aligned reference
    assert _frame_target(frames)[1].endswith("does not hold.")
    assert _frame_target({"coarse": 28.0, "aligned (no Refiner)": 30.0}) == []  # a report without the Refiner's rows


def test_no_row_learns_pose_corrections():
    """On fitted subjects (--poses fit: trioman fit's, where corrections are on by default without --augment) every
    row, the control's included, trains without them: the rows differ by the augmentation alone."""
    from collections import defaultdict
    from pathlib import Path

    from trioman.bench.ablation.plan import _train_config
    from trioman.bench.ablation_config import ALL_VARIANTS
    from trioman.toolkit.train.config import FITTED_BY, with_subject_defaults

    models = defaultdict(lambda: Path("model.onnx"))
    for name, *_ in ALL_VARIANTS:
        cfg = with_subject_defaults(_train_config(name, 0, AblationPlan(detail_sigma=2.0), models), FITTED_BY)
        assert cfg.refine_poses is False, name
