"""Refiner/Examiner training glue and `bench models` on a fabricated corpus (random triplet files: the
glue, not the models' quality, is under test here; the models have their own tests)."""

import dataclasses
import json

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from tests.toolkit.factories import S  # noqa: E402
from trioman.cli import main  # noqa: E402
from trioman.bench.models import ModelsBenchConfig, bench_models, models_markdown  # noqa: E402
from trioman.toolkit.corpus.training import FitConfig, random_crop  # noqa: E402
from trioman.toolkit.corpus.triplets import TripletSet  # noqa: E402


def test_random_crop_takes_one_window_per_sample(corpus):
    ts = TripletSet.load([corpus / "triplets" / "all" / "s00.npz"])
    t = ts.sample(np.random.default_rng(0), 3)
    c = random_crop(t, 16, np.random.default_rng(1))
    assert c.gt.shape == (3, 16, 16, 3) and c.mask.shape == (3, 16, 16)
    for b in range(3):  # every image of a sample is cut at the same place
        hits = [(y, x) for y in range(S - 15) for x in range(S - 15) if np.array_equal(t.gt[b, y:y + 16, x:x + 16], c.gt[b])]
        assert any(np.array_equal(t.coarse[b, y:y + 16, x:x + 16], c.coarse[b]) for y, x in hits)
    assert random_crop(t, None, np.random.default_rng(0)) is t
    with pytest.raises(ValueError, match="crop: must be a multiple of 16"):
        FitConfig(crop=20)


def test_train_commands_and_bench_models(corpus, tmp_path):
    run = tmp_path / "ref"
    assert main(["train-refiner", "--corpus", str(corpus), "--out", str(run), "--steps", "2", "--batch", "2",
                 "--crop", "16", "--conditions", "tex"]) == 0
    info = json.loads((run / "fit.json").read_text())
    assert info["conditions"] == "tex" and info["config"]["image_size"] == 16 and (run / "checkpoints").is_dir()
    files = [str(corpus / "triplets" / "all" / f"{s}.npz") for s in ("s00", "s01")]  # triplet files, the default conditions
    assert main(["train-refiner", "--triplets", *files, "--out", str(tmp_path / "reft"), "--steps", "2", "--batch", "2",
                 "--crop", "16"]) == 0
    info = json.loads((tmp_path / "reft" / "fit.json").read_text())
    assert info["conditions"] == "warp+geo" and info["config"]["image_size"] == 16
    assert main(["train-examiner", "--corpus", str(corpus), "--out", str(tmp_path / "ex"), "--steps", "2", "--batch", "2"]) == 0
    info = json.loads((tmp_path / "ex" / "fit.json").read_text())
    assert info["fit"]["pairing"] == "contrast" and info["fit"]["validation_subjects"] == 1 and info["selected_step"] == 2
    assert main(["train-examiner", "--corpus", str(corpus), "--out", str(tmp_path / "ex0"), "--steps", "2", "--batch", "2",
                 "--validation-subjects", "0"]) == 0
    assert "selected_step" not in json.loads((tmp_path / "ex0" / "fit.json").read_text())
    assert main(["train-examiner", "--corpus", str(corpus), "--out", str(tmp_path / "exp"), "--steps", "2", "--batch", "2",
                 "--pairing", "paper"]) == 0
    info = json.loads((tmp_path / "exp" / "fit.json").read_text())
    assert info["fit"]["pairing"] == "paper" and info["config"]["dual_attention"] == "channel"
    config = ModelsBenchConfig(corpus=str(corpus), subjects=2, heldout=1, size=S, out=str(tmp_path / "bench"),
                               refiner_steps=2, examiner_steps=2, batch=2, examiner="examiner_nano", crop=16,
                               refiner_size="compact", baseline_frames=("all",))
    r = bench_models(config)
    assert r["heldout_test_frames"] == 3
    assert set(r["metrics"]) == {"coarse", "refined (none)", "refined (tex)", "refined (tex+geo)", "refined (warp)", "refined (warp+geo)"}
    assert all(np.isfinite(v) for m in r["metrics"].values() for v in m.values())
    assert 0 <= r["examiner_auroc_real_vs_coarse"] <= 1 and 0 <= r["examiner_auroc_real_vs_coarse_nearby"] <= 1 and (tmp_path / "bench" / "examiner_scores.png").is_file()
    assert "Examiner AUROC" in models_markdown(r) and "the paper's pairs" in models_markdown(r)
    assert r["examiner_selection"]["selected_step"] == 2 and "Examiner weights of step 2" in models_markdown(r)
    again = bench_models(config)  # complete runs are reused, with the timings of the run that trained
    assert again["training"] == r["training"]


def test_training_on_triplet_files_at_another_size(corpus, tmp_path):
    """Models train on a list of triplet files (one subject's) and the Examiner on resized frames."""
    from trioman.toolkit.corpus.training import fit_examiner, training_triplets

    files = [corpus / "triplets" / "all" / "s00.npz"]
    assert training_triplets(files) == files
    with pytest.raises(ValueError, match="no triplet files"):
        training_triplets([])
    small = TripletSet.load(files).resized(16)
    assert small.gt.shape == (8, 16, 16, 3) and small.mask.shape == (8, 16, 16) and small.gt.dtype == np.uint8
    model, info = fit_examiner(files, tmp_path / "ex", fit=FitConfig(steps=2, batch=2, crop=None, image_size=16),
                               validation_subjects=0)
    assert model.config.img_size == 16 and info["fit"]["image_size"] == 16 and "selected_step" not in info
    with pytest.raises(ValueError, match=r"validation_subjects: must be an integer in \[0, 0\] for 1 training subjects, got 1"):
        fit_examiner(files, tmp_path / "ex1", fit=FitConfig(steps=2, batch=2, crop=None))
    with pytest.raises(ValueError, match="image_size"):
        FitConfig(image_size=20)


def test_fit_records_written_before_a_field_was_added_still_match(tmp_path):
    from trioman.toolkit.corpus.training import _same_fit

    new = dataclasses.asdict(FitConfig(steps=3))
    old = {k: v for k, v in new.items() if k != "image_size"}
    assert _same_fit(old, new) and not _same_fit(old, dict(new, image_size=32))


def test_resuming_a_run_to_more_steps_keeps_its_total_wall_time(corpus, tmp_path):
    from trioman.toolkit.corpus.training import _earlier_seconds, fit_examiner

    fit = FitConfig(steps=2, batch=2, crop=None)
    _, first = fit_examiner(corpus, tmp_path / "ex", fit=fit)
    _, more = fit_examiner(corpus, tmp_path / "ex", fit=dataclasses.replace(fit, steps=3))
    assert more["fit"]["steps"] == 3 and more["seconds"] > first["seconds"]
    run = tmp_path / "rec"
    run.mkdir()
    (run / "fit.json").write_text(json.dumps({"fit": dataclasses.asdict(FitConfig(steps=1000)), "seconds": 100.0}))
    assert _earlier_seconds(run, dataclasses.asdict(FitConfig(steps=2500))) == 100.0  # resumed to more steps
    assert _earlier_seconds(run, dataclasses.asdict(FitConfig(steps=1000))) == 0.0  # the same run again
    assert _earlier_seconds(run, dataclasses.asdict(FitConfig(steps=2500, batch=8))) == 0.0  # another fit
    assert _earlier_seconds(tmp_path / "none", dataclasses.asdict(fit)) == 0.0


def test_examiner_keeps_the_step_validated_best_on_held_out_training_subjects(corpus, tmp_path):
    """The last training subject is held out; every validate_every steps its AUROC is recorded and the
    model, fit.json and run/selected.pt (what export and bench deploy load) name the best step."""
    from trioman.toolkit.examiner import load_examiner, pair_auroc
    from trioman.toolkit.corpus.training import examiner_batch, fit_examiner
    from trioman.toolkit.loops.checkpoint import latest_checkpoint, load_checkpoint, model_checkpoint

    run = tmp_path / "ex"
    model, info = fit_examiner(corpus, run, fit=FitConfig(steps=4, batch=2, crop=None), validate_every=2)
    assert info["fit"]["validation_subjects"] == 1 and set(info["validation_auroc"]) == {"2", "4"}
    best = max(info["validation_auroc"].items(), key=lambda kv: (kv[1], -int(kv[0])))
    assert info["selected_step"] == int(best[0]) and info["checkpoint"] == str(run / "selected.pt")
    assert model_checkpoint(run) == run / "selected.pt" and latest_checkpoint(run).name == "ckpt_0000004.pt"
    assert load_checkpoint(run / "selected.pt")["step"] == info["selected_step"]
    held = examiner_batch(TripletSet.load([corpus / "triplets" / "all" / "s01.npz"]).nearby(None, 4, 0))
    reloaded = load_examiner(run / "selected.pt")
    assert pair_auroc(reloaded, held.gt, held.coarse, held.reference) == pytest.approx(best[1], abs=1e-12)
    assert pair_auroc(model, held.gt, held.coarse, held.reference) == pytest.approx(best[1], abs=1e-12)
    with pytest.raises(ValueError, match="validate_every: must be a positive integer, got 0"):
        fit_examiner(corpus, tmp_path / "ex0", fit=FitConfig(steps=2, batch=2, crop=None), validate_every=0)
    with pytest.raises(ValueError, match=r"validation_subjects: must be an integer in \[0, 1\]"):
        fit_examiner(corpus, tmp_path / "ex2", fit=FitConfig(steps=2, batch=2, crop=None), validation_subjects=2)


def _one_line_error(capsys) -> str:
    said = capsys.readouterr()
    assert said.out == "" and len(said.err.strip().splitlines()) == 1, said
    return said.err.strip()


def test_a_resume_with_another_crop_names_the_fields_and_the_command(corpus, tmp_path, capsys, monkeypatch):
    """Issue 26 (minor): a resume refused for a changed --crop dumped both whole configs."""
    from trioman.toolkit.examiner import examiner_config
    from trioman.toolkit.corpus.training import REFINER_SIZES
    from trioman.toolkit.refiner import RefinerConfig
    from trioman.toolkit.loops.checkpoint import save_checkpoint

    monkeypatch.delenv("TRIOMAN_LPIPS_DIR", raising=False)
    run = tmp_path / "ref"  # a run started with --crop 16 --conditions tex (its checkpoint, weights aside)
    config = RefinerConfig(image_size=16, conditions="tex", **REFINER_SIZES["compact"]).to_dict()
    save_checkpoint(run, 2, {"step": 2, "model": {}, "config": config})
    argv = ["train-refiner", "--corpus", str(corpus), "--out", str(run), "--steps", "4", "--batch", "2", "--crop", "32"]
    assert main([*argv, "--conditions", "tex"]) == 1
    err = _one_line_error(capsys)
    assert "the run's Refiner differs from this one (image_size: 16 -> 32); resume it with" in err
    assert f"`trioman train-refiner --corpus {corpus} --out {run} --conditions tex --steps 4 --batch 2 --crop 16`" in err
    assert main(argv) == 1  # two fields differ: both named, nothing else
    err = _one_line_error(capsys)
    assert "(image_size: 16 -> 32, conditions: 'tex' -> 'warp+geo')" in err and "latent_channels" not in err

    run = tmp_path / "exa"  # an Examiner run started with --model examiner_tiny
    save_checkpoint(run, 2, {"step": 2, "model": {}, "config": examiner_config("examiner_tiny", img_size=S).to_dict()})
    assert main(["train-examiner", "--corpus", str(corpus), "--out", str(run), "--steps", "4", "--batch", "2"]) == 1
    err = _one_line_error(capsys)
    assert "the run's Examiner differs from this one (patch_size: 16 -> 8, " in err and "img_size" not in err
    assert f"`trioman train-examiner --corpus {corpus} --out {run} --model examiner_tiny --steps 4 --batch 2`" in err
    save_checkpoint(run, 3, {"step": 3, "model": {}, "config": examiner_config("examiner_nano", img_size=2 * S).to_dict()})
    assert main(["train-examiner", "--corpus", str(corpus), "--out", str(run), "--steps", "4", "--batch", "2"]) == 1
    err = _one_line_error(capsys)
    assert f"(img_size: {2 * S} -> {S}); the run's Examiner sees {2 * S} px images, this corpus's are {S} px" in err
