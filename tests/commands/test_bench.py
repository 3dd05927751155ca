"""``trioman bench``: each target's library function takes a typed config built from the parsed options
(trioman/commands/bench.py), so trioman.bench knows nothing of the command line."""

import dataclasses
import importlib
from pathlib import Path

import pytest

pytest.importorskip("torch")

from trioman.cli import build_parser, main  # noqa: E402
from trioman.commands.bench import TARGETS, bench_config  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
CONFIGURED = {t: (m, c) for t, (m, _, _, c) in TARGETS.items() if c is not None}


def config_of(argv: list[str]):
    args = build_parser().parse_args(["bench", *argv])
    module, cls = CONFIGURED[args.target]
    return bench_config(getattr(importlib.import_module(module), cls), args)


@pytest.mark.parametrize("target", sorted(CONFIGURED))
def test_the_command_lines_defaults_are_the_configs(target):
    module, cls = CONFIGURED[target]
    cls = getattr(importlib.import_module(module), cls)
    assert dataclasses.is_dataclass(cls) and cls.__dataclass_params__.frozen
    assert config_of([target]) == cls()


def test_options_become_typed_fields():
    train = config_of(["train", "--presets", "quick,", "--no-training", "--threads", "1", "--out", "o", "--size", "32"])
    assert (train.presets, train.training, train.threads, train.out, train.size) == (("quick",), False, 1, "o", 32)
    models = config_of(["models", "--baseline-frames", "all,subset", "--backbone", "sd-turbo"])
    assert (models.baseline_frames, models.backbone, models.heldout, models.size) == (("all", "subset"), "sd-turbo", 2, 128)
    assert config_of(["stability", "--seeds", "1", "--iterations", "3"]).iterations == 3
    assert config_of(["deploy", "--frames", "4"]).frames == 4 and config_of(["deploy"]).frames is None


@pytest.mark.parametrize("argv, problem", [
    (["frames", "--frames", "0"], "frames: must be an integer >= 1, got 0"),
    (["scale", "--size", "20"], "size: must be a multiple of 16"),
    (["train", "--presets", "quick,fast"], "presets: unknown 'fast'"),
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
    for module, _ in CONFIGURED.values():
        path = ROOT / "bench" / f"{module.rsplit('.', 1)[1]}.py"
        assert "argparse" not in path.read_text(), path
    assert "argparse" not in (ROOT / "bench" / "demo.py").read_text()
