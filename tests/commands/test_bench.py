"""``trioman bench``: each target's library function takes a typed config built from the options of its sub-parser
(trioman/commands/bench.py), so trioman.bench knows nothing of the command line."""

import dataclasses
from pathlib import Path

import pytest

pytest.importorskip("torch")

from trioman.cli import build_parser, main  # noqa: E402
from trioman.toolkit.train.augment_config import AugmentConfig  # noqa: E402
from trioman.commands.bench import TARGETS, _target_configs, target_config  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]


def config_of(argv: list[str]):
    return target_config(build_parser().parse_args(["bench", *argv]))


@pytest.mark.parametrize("target", sorted(TARGETS))
def test_the_command_lines_defaults_are_the_configs(target):
    cls = _target_configs()[target]
    assert dataclasses.is_dataclass(cls) and cls.__dataclass_params__.frozen
    assert config_of([target]) == cls()


def test_options_become_typed_fields():
    train = config_of(["train", "--presets", "quick,", "--no-training", "--threads", "1", "--out", "o", "--size", "32"])
    assert (train.presets, train.training, train.threads, train.out, train.size) == (("quick",), False, 1, "o", 32)
    models = config_of(["models", "--baseline-frames", "all,subset", "--backbone", "sd-turbo"])
    assert (models.baseline_frames, models.backbone, models.heldout, models.size) == (("all", "subset"), "sd-turbo", 2, 128)
    assert config_of(["stability", "--seeds", "1", "--iterations", "3"]).iterations == 3
    assert config_of(["deploy", "--frames", "4"]).frames == 4 and config_of(["deploy"]).frames is None
    ablation = config_of(["ablation", "--augment-pool", "8", "--iterations", "30", "--variants", "G,GRE", "--no-training"])
    assert (ablation.plan.schedule.pool, ablation.plan.iterations, ablation.variants, ablation.training) == \
        (8, 30, ("G", "GRE"), False)
    assert ablation.plan.schedule == dataclasses.replace(AugmentConfig(), pool=8)


def test_an_option_belongs_to_its_targets():
    with pytest.raises(SystemExit):
        build_parser().parse_args(["bench", "synth", "--corpus", "c"])


@pytest.mark.parametrize("argv, problem", [
    (["frames", "--frames", "0"], "frames: must be an integer >= 1, got 0"),
    (["scale", "--size", "20"], "size: must be a multiple of 16"),
    (["train", "--presets", "quick,fast"], "--presets: expected one of quick, full, got 'fast'"),
    (["ablation", "--reach", "11"], "--reach: the Generator's camera sigmas"),
    (["ablation", "--augment-start", "1"], "--augment-start: must lie in [0, 1), got 1.0"),
    (["synth", "--seed", "-1"], "seed: must be an integer >= 0, got -1"),
    (["stability", "--iterations", "0"], "iterations: must be an integer >= 1, got 0"),
])
def test_a_bad_value_is_one_line_naming_the_field_before_any_work(argv, problem, tmp_path, capsys):
    out = tmp_path / "bench"
    assert main(["bench", *argv, "--out", str(out)]) == 1
    err = capsys.readouterr().err
    assert problem in err and len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert not out.exists()


def test_the_library_takes_no_parsed_options():
    for module, *_ in TARGETS.values():
        name = module.rsplit(".", 1)[1]
        paths = [*(ROOT / "bench").glob(f"{name}.py"), *(ROOT / "bench" / name).glob("*.py")]  # a module or a package
        assert paths, module
        for path in paths:
            assert "argparse" not in path.read_text(), path
    assert "argparse" not in (ROOT / "trioman" / "demo.py").read_text()
