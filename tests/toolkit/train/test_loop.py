"""Training and evaluation on a tiny synthetic subject: the loss goes down, resume is exact, reports exist."""

import csv
import dataclasses
import json
import shutil

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("anny")

from tests.conftest import run_python  # noqa: E402
from tests.toolkit.train.factories import TINY_AVATAR  # noqa: E402
from trioman.toolkit.evaluate import evaluate, load_run  # noqa: E402
from trioman.toolkit.synth.subject import SynthConfig, synthesize_subject  # noqa: E402
from trioman.toolkit.loops.checkpoint import list_checkpoints, load_checkpoint  # noqa: E402
from trioman.toolkit.train.config import TrainConfig, preset  # noqa: E402
from trioman.toolkit.train.loop import train  # noqa: E402


@pytest.fixture(scope="module")
def subject(tmp_path_factory):
    out = tmp_path_factory.mktemp("subj") / "s"
    synthesize_subject(SynthConfig(seed=5, size=32, frames=10, texture_size=256), out, progress=False)
    return out


def losses(run) -> np.ndarray:
    with open(run / "train_log.csv") as f:
        return np.array([float(r["loss"]) for r in csv.DictReader(f)])


def test_training_lowers_the_loss(subject, tmp_path):
    cfg = TrainConfig(iterations=60, lr=1e-2, random_background=False, checkpoint_every=60, avatar=TINY_AVATAR)
    run = train(subject, tmp_path / "run", cfg, progress=False)
    loss = losses(run)
    assert len(loss) == 60 and np.all(np.isfinite(loss))
    assert loss[-10:].mean() < 0.8 * loss[:10].mean(), (loss[:10].mean(), loss[-10:].mean())
    saved = json.loads((run / "config.json").read_text())
    # the record holds the config as trained: the subject-dependent defaults resolved (a synthetic subject: no pose
    # corrections)
    assert TrainConfig.from_dict(saved["train"]) == dataclasses.replace(cfg, refine_poses=False) and saved["subject"] == str(subject.resolve())


def test_resume_after_interruption_matches_an_uninterrupted_run(subject, tmp_path):
    cfg = TrainConfig(iterations=6, checkpoint_every=3, avatar=TINY_AVATAR)
    straight = train(subject, tmp_path / "a", cfg, progress=False)
    broken = train(subject, tmp_path / "b", cfg, progress=False, stop_after=4)  # killed after step 4
    assert [p.name for p in list_checkpoints(broken)] == ["ckpt_0000003.pt"]
    train(subject, broken, cfg, resume=True, progress=False)
    a, b = load_checkpoint(list_checkpoints(straight)[-1]), load_checkpoint(list_checkpoints(broken)[-1])
    assert a["step"] == b["step"] == 6
    for key in a["model"]:
        torch.testing.assert_close(a["model"][key], b["model"][key], rtol=0, atol=1e-6)
    torch.testing.assert_close(a["optimizer"]["state"], b["optimizer"]["state"], rtol=0, atol=1e-6)
    assert (a["numpy_rng"], a["skipped"], a["config"]) == (b["numpy_rng"], b["skipped"], b["config"])
    assert torch.equal(a["torch_rng"], b["torch_rng"]) and list(a) == list(b)  # the same entries, in the same order
    np.testing.assert_allclose(losses(straight), losses(broken), atol=1e-6)  # the log was trimmed and rewritten
    assert not list((broken / "checkpoints").glob(".*")), "no temporary files left behind"


def test_point_colours_train_at_their_own_decaying_learning_rate(subject, tmp_path):
    avatar = dataclasses.replace(TINY_AVATAR, point_colors=True)
    cfg = TrainConfig(iterations=4, checkpoint_every=4, lr=1e-3, point_color_lr=5e-2, lr_decay_at=(0.5, 0.9), avatar=avatar)
    state = load_checkpoint(list_checkpoints(train(subject, tmp_path / "p", cfg, progress=False))[-1])
    groups = state["optimizer"]["param_groups"]
    assert [len(g["params"]) for g in groups][1] == 1  # point_rgb alone
    assert groups[0]["lr"] == pytest.approx(1e-4) and groups[1]["lr"] == pytest.approx(5e-3)  # step 3: x0.1
    assert state["model"]["point_rgb"].shape == (load_run(tmp_path / "p")[0].num_gaussians, 3)
    assert state["model"]["point_rgb"].abs().max() > 1e-3


def test_refuses_to_overwrite_a_run_and_reports_bad_checkpoints(subject, tmp_path):
    cfg = TrainConfig(iterations=2, checkpoint_every=2, avatar=TINY_AVATAR)
    run = train(subject, tmp_path / "r", cfg, progress=False)
    with pytest.raises(FileExistsError, match="pass `resume`"):
        train(subject, run, cfg, progress=False)
    ckpt = list_checkpoints(run)[-1]
    ckpt.write_bytes(ckpt.read_bytes()[:100])  # truncated
    with pytest.raises(ValueError, match="not a readable checkpoint"):
        load_checkpoint(ckpt)


def test_evaluate_writes_every_report(subject, tmp_path):
    cfg = TrainConfig(iterations=3, checkpoint_every=3, avatar=TINY_AVATAR)
    run = train(subject, tmp_path / "e", cfg, progress=False)
    summary = evaluate(run, "test", progress=False)
    out = run / "eval_test"
    for name in ("metrics.csv", "summary.json", "report.md", "grid.png", "video.mp4"):
        assert (out / name).stat().st_size > 0, name
    assert summary["frames"] == 4 and summary["lpips"].startswith("not computed")
    assert np.isfinite(summary["mean"]["psnr"]) and 0 < summary["mean"]["ssim"] <= 1
    # The masked protocol puts both images on white with the GT mask: it can only agree more than unmasked.
    assert summary["mean"]["psnr"] >= summary["mean"]["psnr_unmasked"] - 1e-6
    model, _, _, step = load_run(run)
    assert step == 3 and model.num_gaussians > 0


def test_presets_and_bad_values():
    assert preset("quick").iterations < preset("full").iterations
    with pytest.raises(ValueError, match="preset: unknown preset 'fast'"):
        preset("fast")
    with pytest.raises(ValueError, match="iterations"):
        TrainConfig(iterations=0)
    with pytest.raises(ValueError, match="image_scale"):
        TrainConfig(image_scale=2.0)
    with pytest.raises(ValueError, match="point_color_lr: must be > 0, got 0"):
        TrainConfig(point_color_lr=0)


def test_training_leaves_the_subnormal_setting_as_it_found_it(subject, tmp_path):
    from trioman.toolkit.cpu import denormals_flushed

    assert not denormals_flushed()
    train(subject, tmp_path / "d", TrainConfig(iterations=1, checkpoint_every=1, avatar=TINY_AVATAR), progress=False)
    assert not denormals_flushed()


# --------------------------------------------------------------------------------------------------
# resume checks what it resumes; a bad input leaves no run; deterministic weights (issue 18, cases 1, 3, 4, 6)


def copy_subject(subject, dest):
    shutil.copytree(subject, dest)
    return dest


def test_resume_refuses_another_subject_config_or_code_naming_what_differs(subject, tmp_path, monkeypatch):
    cfg = TrainConfig(iterations=4, checkpoint_every=2, avatar=TINY_AVATAR)
    mine = copy_subject(subject, tmp_path / "mine")
    run = train(mine, tmp_path / "run", cfg, progress=False, stop_after=2)  # killed after its first checkpoint
    record = (run / "config.json").read_text()
    other = copy_subject(subject, tmp_path / "other")  # same content, another subject folder
    with pytest.raises(ValueError, match=rf"resume: .*config.json: the run trains on the subject {mine}, not {other}"):
        train(other, run, cfg, resume=True, progress=False)
    with pytest.raises(ValueError, match=r"the training config differs from the run's \(iterations: 4 -> 5000; "
                                         r"preset: 'quick' -> 'full'; seed: 0 -> 7\).*`extend_iterations`"):
        train(mine, run, dataclasses.replace(cfg, preset="full", seed=7, iterations=5000), resume=True, progress=False)
    import trioman.toolkit.train.resume as resume_module

    monkeypatch.setattr(resume_module, "__version__", "9.9.9")
    with pytest.raises(ValueError, match=r"the run was made by trioman 0\.1\.0, this is trioman 9\.9\.9"):
        train(mine, run, cfg, resume=True, progress=False)
    monkeypatch.undo()
    mask = sorted((mine / "masks").iterdir())[0]
    shutil.copy(sorted((mine / "masks").iterdir())[1], mask)  # the subject's content changes under the run
    with pytest.raises(ValueError, match=rf"the subject {mine} changed since the run started"):
        train(mine, run, cfg, resume=True, progress=False)
    assert (run / "config.json").read_text() == record
    assert [p.name for p in list_checkpoints(run)] == ["ckpt_0000002.pt"]


def test_extend_iterations_continues_the_run_and_records_it(subject, tmp_path):
    cfg = TrainConfig(iterations=2, checkpoint_every=2, avatar=TINY_AVATAR)
    run = train(subject, tmp_path / "run", cfg, progress=False)
    with pytest.raises(ValueError, match="extend_iterations: 2 is not more than the run's 2 iterations"):
        train(subject, run, cfg, resume=True, progress=False, extend_iterations=2)
    with pytest.raises(ValueError, match="extend_iterations: needs `resume`"):
        train(subject, tmp_path / "new", cfg, progress=False, extend_iterations=4)
    train(subject, run, cfg, resume=True, progress=False, extend_iterations=4)
    assert load_checkpoint(list_checkpoints(run)[-1])["step"] == 4 and len(losses(run)) == 4
    saved = json.loads((run / "config.json").read_text())
    assert saved["train"]["iterations"] == 4 and saved["config_hash"] == dataclasses.replace(cfg, iterations=4, refine_poses=False).digest()
    assert [(e["from_step"], e["iterations_before"], e["iterations"]) for e in saved["extensions"]] == [(2, 2, 4)]
    train(subject, run, dataclasses.replace(cfg, iterations=4), resume=True, progress=False)  # the extended run resumes


def test_a_train_that_fails_on_a_bad_input_leaves_no_run(subject, tmp_path):
    broken = copy_subject(subject, tmp_path / "broken")
    image = sorted((broken / "images").iterdir())[0]
    good = image.read_bytes()
    image.write_bytes(good[:40])  # the PNG header passes validation, the pixels do not decode
    cfg = TrainConfig(iterations=1, checkpoint_every=1, avatar=TINY_AVATAR)
    with pytest.raises(ValueError, match=rf"{image.name}: not a readable image"):
        train(broken, tmp_path / "run", cfg, progress=False)
    assert not (tmp_path / "run").exists()
    image.write_bytes(good)
    train(broken, tmp_path / "run", cfg, progress=False)  # the rerun after the fix needs no --resume


def test_resume_removes_temporary_files_and_nothing_else(subject, tmp_path):
    cfg = TrainConfig(iterations=4, checkpoint_every=2, avatar=TINY_AVATAR)
    run = train(subject, tmp_path / "run", cfg, progress=False, stop_after=2)
    stray = [run / "checkpoints" / ".ckpt_0000004.pt.0123abcd.tmp.pt", run / ".train_log.csv.deadbeef.tmp.csv"]
    for p in stray:
        p.write_bytes(b"left by kill -9")
    (run / "notes.txt").write_text("mine")
    train(subject, run, cfg, resume=True, progress=False)
    assert not any(p.exists() for p in stray) and (run / "notes.txt").read_text() == "mine"


@pytest.fixture
def two_threads():
    threads = torch.get_num_threads()
    torch.set_num_threads(2)
    yield
    torch.set_num_threads(threads)


def test_kill_9_and_resume_gives_the_weights_of_an_uninterrupted_run(subject, tmp_path, two_threads):
    # Default settings at two torch threads: the killed process is a real SIGKILL right after its first checkpoint.
    cfg = TrainConfig(iterations=6, checkpoint_every=3, avatar=TINY_AVATAR)
    killed = tmp_path / "killed"
    proc = run_python(f"""
        import os, signal, torch
        torch.set_num_threads(2)
        from trioman.toolkit.avatar.model import AvatarConfig
        from trioman.toolkit.train.config import TrainConfig
        from trioman.toolkit.train.loop import train
        cfg = TrainConfig.from_dict({cfg.to_dict()!r})
        train({str(subject)!r}, {str(killed)!r}, cfg, progress=False,
              on_checkpoint=lambda step, path: os.kill(os.getpid(), signal.SIGKILL))
    """, timeout=600)
    assert proc.returncode == -9, proc.stderr
    assert [p.name for p in list_checkpoints(killed)] == ["ckpt_0000003.pt"]
    train(subject, killed, cfg, resume=True, progress=False)
    straight = train(subject, tmp_path / "straight", cfg, progress=False)
    a, b = load_checkpoint(list_checkpoints(straight)[-1]), load_checkpoint(list_checkpoints(killed)[-1])
    assert a["step"] == b["step"] == 6
    for key in a["model"]:
        torch.testing.assert_close(a["model"][key], b["model"][key], rtol=0, atol=0)
    np.testing.assert_array_equal(losses(straight), losses(killed))
    assert json.loads((killed / "config.json").read_text())["threads"] == 2


def test_command_line_resume_refusal_and_extension(subject, tmp_path, capsys, monkeypatch):
    from trioman.cli import main

    monkeypatch.delenv("TRIOMAN_LPIPS_DIR", raising=False)
    out = str(tmp_path / "cli")
    assert main(["train", str(subject), "--out", out, "--iterations", "2", "--quiet"]) == 0
    assert capsys.readouterr().out.count("LPIPS not computed") == 1  # once the run has trained
    assert main(["train", str(subject), "--out", out, "--iterations", "2", "--resume", "--seed", "7", "--quiet"]) == 1
    said = capsys.readouterr()
    assert said.out == "" and len(said.err.strip().splitlines()) == 1  # the refusal alone, no LPIPS note
    err = said.err
    assert "Traceback" not in err and "the training config differs from the run's (seed: 0 -> 7)" in err
    assert err.startswith("trioman train: error: --resume: ") and "(or --extend-iterations N to continue it" in err
    assert main(["train", str(subject), "--out", out, "--iterations", "2", "--quiet"]) == 1
    assert "a run is already there (pass --resume to continue it, or choose another --out)" in capsys.readouterr().err
    assert main(["train", str(subject), "--out", out, "--resume", "--extend-iterations", "3", "--quiet"]) == 0
    assert json.loads((tmp_path / "cli" / "config.json").read_text())["extensions"][0]["iterations"] == 3




def test_an_error_before_training_is_one_line_without_the_lpips_note(tmp_path, capsys, monkeypatch):
    """Issue 26 (minor): 'LPIPS not computed' came before every error, so errors were two lines."""
    from trioman.cli import main

    monkeypatch.delenv("TRIOMAN_LPIPS_DIR", raising=False)
    taken = tmp_path / "taken"
    taken.mkdir()
    (taken / "config.json").write_text("{}")
    out = str(tmp_path / "run")
    for argv in (["train", str(tmp_path / "missing"), "--out", out], ["train", str(tmp_path), "--out", str(taken)],
                 ["train", str(tmp_path), "--out", out, "--extend-iterations", "3"],
                 ["train", str(tmp_path), "--out", out, "--extra-weight", "2"], ["eval", str(tmp_path / "missing")],
                 ["train-refiner", "--corpus", str(tmp_path / "missing"), "--out", out]):
        assert main([*argv, *(["--quiet"] if argv[0] != "train-refiner" else [])]) == 1
        said = capsys.readouterr()
        assert said.out == "" and len(said.err.strip().splitlines()) == 1, (argv, said)

def test_a_full_disk_while_checkpointing_is_enospc_naming_the_checkpoint(tmp_path, monkeypatch):
    # torch.save to a file reported a full disk as "RuntimeError: ... unexpected pos" (issue 18, case 2)
    import errno

    from tests.full_disk import full_disk_open
    from trioman.runtime import outputs
    from trioman.toolkit.loops.checkpoint import checkpoint_path, save_checkpoint

    monkeypatch.setattr(outputs, "open", full_disk_open, raising=False)
    with pytest.raises(OSError) as err:
        save_checkpoint(tmp_path, 5, {"step": 5, "model": {"w": torch.ones(3)}, "config": "{}"})
    assert err.value.errno == errno.ENOSPC and err.value.filename == str(checkpoint_path(tmp_path, 5))
    assert list((tmp_path / "checkpoints").iterdir()) == []


def test_command_line_train_on_a_full_disk_is_one_line_and_leaves_no_run(subject, tmp_path, capsys, monkeypatch):
    from tests.full_disk import full_disk_open
    from trioman.cli import main
    from trioman.runtime import outputs

    monkeypatch.setattr("trioman.toolkit.lpips.load_lpips_or_say_why", lambda command: None)
    monkeypatch.setattr(outputs, "open", full_disk_open, raising=False)
    out = tmp_path / "run"
    assert main(["train", str(subject), "--out", str(out), "--iterations", "2", "--quiet"]) == 1
    err = capsys.readouterr().err
    assert "Traceback" not in err and f"{out / 'config.json'}: no space left on the device" in err
    assert not out.exists()


def test_a_resume_at_another_thread_count_says_so(subject, tmp_path, capsys):
    cfg = TrainConfig(iterations=2, checkpoint_every=1, avatar=TINY_AVATAR)
    threads = torch.get_num_threads()
    try:
        torch.set_num_threads(1)
        run = train(subject, tmp_path / "run", cfg, progress=False, stop_after=1)
        torch.set_num_threads(2)
        train(subject, run, cfg, resume=True, progress=False)
    finally:
        torch.set_num_threads(threads)
    assert json.loads((run / "config.json").read_text())["threads"] == 1
    assert "was trained with 1 torch threads, this process has 2" in capsys.readouterr().err


def test_non_finite_steps_are_skipped_counted_and_stop_the_run(subject, tmp_path, monkeypatch):
    import trioman.toolkit.train.loop as loop

    real = loop.regularisers
    bad_steps = {2, 3}  # calls (0-based) whose loss is NaN
    calls = []  # the weights at each call, before its step's update

    def flaky(model, out, cfg):
        calls.append([p.detach().clone() for p in model.parameters()])
        return real(model, out, cfg) + (float("nan") if len(calls) - 1 in bad_steps else 0.0)

    monkeypatch.setattr(loop, "regularisers", flaky)
    cfg = TrainConfig(iterations=6, checkpoint_every=3, max_skipped=3, avatar=TINY_AVATAR)
    run = train(subject, tmp_path / "g", cfg, progress=False)
    ckpts = list_checkpoints(run)
    states = [load_checkpoint(c) for c in ckpts]
    assert [s["skipped"] for s in states] == [1, 2]  # counted (steps 3 and 4), and the run went on
    assert all(torch.isfinite(v).all() for v in states[-1]["model"].values())
    assert np.isnan(losses(run)[2:4]).all() and np.isfinite(losses(run)[[0, 1, 4, 5]]).all()
    same = [all(torch.equal(a, b) for a, b in zip(calls[i], calls[i + 1])) for i in range(5)]
    assert same == [False, False, True, True, False]  # the skipped steps 2 and 3 left the weights as they were

    calls.clear()
    bad_steps.update(range(100))
    with pytest.raises(FloatingPointError, match=r"train: 3 consecutive steps .* were skipped; the run stops"):
        train(subject, tmp_path / "h", cfg, progress=False)
    assert not list_checkpoints(tmp_path / "h")  # no checkpoint of a broken run
    with pytest.raises(ValueError, match="max_skipped: must be a positive integer, got 0"):
        TrainConfig(max_skipped=0)


def test_evaluate_at_the_true_poses(subject, tmp_path):
    """poses="true" renders at poses_true: the same as the stored poses on a noise-free subject, not on a noisy one."""
    noisy = tmp_path / "noisy"
    synthesize_subject(SynthConfig(seed=5, size=32, frames=10, texture_size=256, pose_noise_deg=8.0), noisy, progress=False)
    cfg = TrainConfig(iterations=3, checkpoint_every=3, avatar=TINY_AVATAR)
    for subj, same in ((subject, True), (noisy, False)):
        run = train(subj, tmp_path / f"run_{same}", cfg, progress=False)
        stored = evaluate(run, "test", tmp_path / f"stored_{same}", progress=False, video=False)
        true = evaluate(run, "test", tmp_path / f"true_{same}", progress=False, video=False, poses="true")
        assert (stored["poses"], true["poses"]) == ("stored", "true")
        assert (stored["mean"]["psnr"] == true["mean"]["psnr"]) == same
    with pytest.raises(ValueError, match="poses: expected"):
        evaluate(run, "test", progress=False, poses="fitted")


def test_one_writer_per_run(subject, tmp_path, capsys):
    # issue 41: two `train` into one --out both wrote its checkpoints; a killed run's lock file stops no resume
    import os

    from trioman.cli import main
    from trioman.runtime.outputs import process_lock

    run, lock = tmp_path / "r", tmp_path / ".r.train.lock"
    with process_lock(lock, "the first run"):
        assert main(["train", str(subject), "--out", str(run), "--iterations", "2", "--quiet"]) == 1
        assert f"--out: another `train` into {run} is running (pid {os.getpid()}" in capsys.readouterr().err
    assert not run.exists()
    lock.write_text("left by kill -9")
    assert main(["train", str(subject), "--out", str(run), "--iterations", "2", "--quiet"]) == 0
    assert not lock.exists() and (run / "config.json").is_file()


def test_a_new_run_takes_only_an_absent_or_empty_folder_outside_its_inputs(subject, tmp_path, capsys):
    # issue 41, D3: `train --out` into the subject, an avatar, `.` or a folder of another run's checkpoints
    from trioman.cli import main

    other = tmp_path / "other"
    (other / "checkpoints").mkdir(parents=True)
    (other / "checkpoints" / "ckpt_000100.pt").write_bytes(b"someone else's")
    (other / "train_log.csv").write_text("step,loss\n")
    before = {p: p.read_bytes() for p in subject.rglob("*") if p.is_file()}
    cases = [(other, "folder exists and is not empty (choose another output folder)"),
             (subject, f"--out: {subject}: is the input {subject}"),
             (subject / "run", f"--out: {subject / 'run'}: lies inside the input {subject}"),
             (tmp_path, "folder exists and is not empty")]
    for out, message in cases:
        assert main(["train", str(subject), "--out", str(out), "--iterations", "2", "--quiet"]) == 1
        err = capsys.readouterr().err
        assert message in err and "Traceback" not in err, err
    assert (other / "checkpoints" / "ckpt_000100.pt").read_bytes() == b"someone else's"
    assert (other / "train_log.csv").read_text() == "step,loss\n" and not (other / "config.json").exists()
    assert {p: p.read_bytes() for p in subject.rglob("*") if p.is_file()} == before
    empty = tmp_path / "empty"
    empty.mkdir()
    assert main(["train", str(subject), "--out", str(empty), "--iterations", "2", "--quiet"]) == 0
