"""``train --resume``: the command that started or extended a run finishes it, and every refusal names the
command that would work (toolkit/train/resume.py; issue 26, case 5)."""

import dataclasses
import json

import pytest

pytest.importorskip("torch")
pytest.importorskip("anny")

from trioman.cli import main  # noqa: E402
from trioman.toolkit.synth.subject import SynthConfig, synthesize_subject  # noqa: E402
from trioman.toolkit.loops.checkpoint import latest_checkpoint, load_checkpoint  # noqa: E402
from tests.toolkit.train.factories import TINY_AVATAR as TINY  # noqa: E402
from trioman.toolkit.train.config import TrainConfig, preset  # noqa: E402
from trioman.toolkit.train.loop import train  # noqa: E402


@pytest.fixture(scope="module")
def subject(tmp_path_factory):
    out = tmp_path_factory.mktemp("subj") / "s"
    synthesize_subject(SynthConfig(seed=5, size=32, frames=6, texture_size=64), out, progress=False)
    return out


def test_an_interrupted_extension_resumes_with_the_same_command(subject, tmp_path, capsys):
    cfg = TrainConfig(iterations=2, checkpoint_every=2, avatar=TINY)
    run = train(subject, tmp_path / "run", cfg, progress=False)
    # `--resume --extend-iterations 4`, killed after one step of the extension (config.json already extended)
    train(subject, run, cfg, resume=True, progress=False, extend_iterations=4, stop_after=1)
    train(subject, run, cfg, resume=True, progress=False, extend_iterations=4)  # the same command finishes it
    assert load_checkpoint(latest_checkpoint(run))["step"] == 4
    record = json.loads((run / "config.json").read_text())
    assert [(e["iterations_before"], e["iterations"]) for e in record["extensions"]] == [(2, 4)]  # one extension
    capsys.readouterr()
    train(subject, run, cfg, resume=True, progress=False)  # the starting command resumes the extended run as recorded
    assert "was extended to 4 iterations" in capsys.readouterr().err
    command = f"`trioman train {subject.resolve()} --out {run} --iterations 2 --resume --extend-iterations 4`"
    for change, extend, problem in ((cfg, 3, "extend_iterations: 3 is not more than the run's 4 iterations; resume it "
                                              f"with {command}"),
                                    (dataclasses.replace(cfg, iterations=3), None, f"iterations: 4 -> 3); resume with the "
                                                                                   f"options the run was started with: "
                                                                                   f"{command}"),
                                    (dataclasses.replace(cfg, seed=7), None, f"seed: 0 -> 7); resume with the options "
                                                                             f"the run was started with: {command}")):
        with pytest.raises(ValueError) as err:
            train(subject, run, change, resume=True, progress=False, extend_iterations=extend)
        assert problem in str(err.value)


def test_the_suggested_command_is_the_runs_own(subject, tmp_path, capsys, monkeypatch):
    monkeypatch.setattr("trioman.toolkit.lpips.load_lpips_or_say_why", lambda command: None)
    from trioman.runtime.formats import load_subject
    from trioman.toolkit.train.resume import new_record, read_record, resume_command, write_record

    run = tmp_path / "run"
    record = {"subject": str(subject.resolve()), "extensions": [],
              "train": preset("full", iterations=7, seed=3, image_scale=0.5).to_dict()}
    assert resume_command(run, record) == (f"trioman train {subject.resolve()} --out {run} --preset full --iterations 7 "
                                           f"--image-scale 0.5 --seed 3 --resume")
    # the command line's refusal is that one line (a run started by `train SUBJECT --out RUN --iterations 1`)
    write_record(run, new_record(load_subject(subject), preset("quick", iterations=1)))
    assert main(["train", str(subject), "--out", str(run), "--iterations", "1", "--seed", "2", "--resume", "--quiet"]) == 1
    err = capsys.readouterr().err
    assert f"`{resume_command(run, read_record(run))}`" in err and "--iterations 1 --resume`" in err


def test_a_run_recorded_before_an_avatar_field_existed_resumes_with_its_preset(subject, tmp_path):
    from trioman.runtime.formats import load_subject
    from trioman.toolkit.train.resume import check_resume, new_record

    subj = load_subject(subject)
    full = preset("full")
    old = dataclasses.replace(full, avatar=dataclasses.replace(full.avatar, pose_subdivisions=None))
    record = new_record(subj, old)
    del record["train"]["avatar"]["pose_subdivisions"]  # config.json as the code before the field wrote it
    cfg, _ = check_resume(tmp_path, record, subj, full, 0, None)
    assert cfg.avatar.pose_subdivisions is None  # the run's avatar, not today's preset's
    record["train"]["avatar"]["pose_subdivisions"] = None  # a recorded value is the run's choice: a change is refused
    with pytest.raises(ValueError, match=r"avatar.pose_subdivisions: None -> 0"):
        check_resume(tmp_path, record, subj, full, 0, None)


@pytest.mark.parametrize("mode, keep_carried", [("refined", True), ("refined", False), ("examined", True), ("aligned", False)])
def test_the_suggested_command_of_an_augmented_run_parses_back_to_its_config(tmp_path, mode, keep_carried):
    # issue 41: the hint compared keep_carried with the dataclass default (False), not the command's (True with a
    # Refiner), and printed `--augment-keep-carried True`, which argparse refuses
    import shlex

    from trioman.cli import build_parser
    from trioman.commands.train import augment_config
    from trioman.toolkit.train.augmentation import AugmentConfig
    from trioman.toolkit.train.resume import resume_command

    models = {}
    if mode != "aligned":
        for name in ("refiner", "examiner") if mode == "examined" else ("refiner",):
            models[name] = str(tmp_path / f"{name}.onnx")
            (tmp_path / f"{name}.onnx").write_bytes(b"")
    aug = AugmentConfig(mode=mode, keep_carried=keep_carried, per_frame=3 if mode == "examined" else None, pool=4, **models)
    record = {"subject": str(tmp_path / "s"), "extensions": [],
              "train": dataclasses.replace(preset("quick"), augment=aug).to_dict()}
    words = shlex.split(resume_command(tmp_path / "run", record))
    assert words[:2] == ["trioman", "train"]
    args = build_parser().parse_args(words[1:])  # argparse exits on a flag it refuses
    assert augment_config(args) == aug and args.resume


def test_the_suggested_command_gives_every_option_the_run_was_started_with(tmp_path):
    # the hint listed its flags by hand and left out --refine-poses, so a run with pose corrections was refused
    import shlex

    from trioman.cli import build_parser
    from trioman.options import given
    from trioman.toolkit.train.config import TrainConfig
    from trioman.toolkit.train.resume import resume_command

    extra = tmp_path / "extra"
    cfg = preset("quick", iterations=9, seed=4, image_scale=0.5, refine_poses=True, extra_frames=str(extra),
                 extra_weight=0.3)
    record = {"subject": str(tmp_path / "s"), "extensions": [], "train": cfg.to_dict()}
    args = build_parser().parse_args(shlex.split(resume_command(tmp_path / "run", record))[1:])
    assert preset(args.preset or "quick", **given(TrainConfig, args, ("iterations", "image_scale", "seed",
                                                                      "refine_poses", "extra_frames",
                                                                      "extra_weight"))) == cfg


@pytest.mark.parametrize("where", ["", "weights.", "avatar."])
def test_a_setting_this_version_does_not_know_is_named_with_the_run_record(subject, tmp_path, capsys, where):
    run = train(subject, tmp_path / "r", TrainConfig(iterations=2, checkpoint_every=2, avatar=TINY), progress=False)
    record = json.loads((run / "config.json").read_text())
    (record["train"] if not where else record["train"][where[:-1]])["pose_align_steps"] = 20
    (run / "config.json").write_text(json.dumps(record))
    with pytest.raises(ValueError, match=rf"^{where}pose_align_steps: not a training setting of this trioman version"):
        TrainConfig.from_dict(record["train"])
    assert main(["eval", str(run), "--no-video", "--quiet"]) == 1
    err = capsys.readouterr().err
    assert "config.json: not a readable run record" in err and f"{where}pose_align_steps" in err
