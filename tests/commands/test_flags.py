"""Library errors name parameters; the commands show their flags (trioman/commands/flags.py, trioman/cli.py)."""

import argparse
import importlib

import pytest

from trioman.cli import COMMANDS, main
from trioman.commands.flags import command_flags, flag_message

FLAGS = {"size": "--size", "per_frame": "--per-frame", "resume": "--resume", "overwrite": "--overwrite",
         "motion": "--motion", "subject": "SUBJECT"}


@pytest.mark.parametrize("message, shown", [
    ("size: must lie in [16, 4096] pixels, got 8", "--size: must lie in [16, 4096] pixels, got 8"),
    ("motion walk: all 3 frames show nothing", "--motion walk: all 3 frames show nothing"),
    ("resume and overwrite: choose one", "--resume and --overwrite: choose one"),
    ("per_frame: give `resume` or `overwrite` with `subject`", "--per-frame: give --resume or --overwrite with SUBJECT"),
    ("out/x.png: missing file", "out/x.png: missing file"),  # a path, not a parameter
    ("seed: expected an integer; `seed` again", "seed: expected an integer; `seed` again"),  # not this command's
    ("no colon and `size`", "no colon and --size"),
])
def test_flag_message(message, shown):
    assert flag_message(message, FLAGS) == shown
    assert flag_message(shown, FLAGS) == shown  # a shown message stays as it is


def _options(module) -> set[str]:
    parser = argparse.ArgumentParser(add_help=False)
    module.add_arguments(parser)
    found = set()

    def walk(p):
        for action in p._actions:
            if isinstance(action, argparse._SubParsersAction):
                for sub in action.choices.values():
                    walk(sub)
            else:
                found.update(action.option_strings or [action.metavar or action.dest])

    walk(parser)
    return found


def test_every_flag_a_command_shows_is_one_of_its_own():
    for cmd in COMMANDS:
        module = importlib.import_module(cmd.module)
        flags = command_flags(module)
        assert set(flags.values()) <= _options(module), (cmd.name, set(flags.values()) - _options(module))


@pytest.mark.parametrize("argv, shown", [
    (["augment", "S", "--avatar", "A", "--out", "O", "--shard", "3/3"],
     "trioman augment: error: --shard: expected I/N with 0 <= I < N (e.g. 0/4), got '3/3'"),
    (["animate", "A", "--motion", "walk", "--out", "v.mp4", "--size", "17"],
     "trioman animate: error: --size: 17 is odd, and an MP4 needs even sides (it would be 16x16); use 16 or 18"),
    (["animate", "A", "--motion", "walk", "--out", "v.mp4", "--background", "1,1"],
     "trioman animate: error: --background: expected three numbers in [0, 1], got '1,1'"),
    (["animate", "A", "--motion", "walk", "--out", "v.mp4", "--azimuth", "nan"],
     "trioman animate: error: --azimuth: must be a finite number of degrees, got nan"),
    (["render", "A", "--out", "x.png", "--background", "red"],
     "trioman render: error: --background: expected r,g,b numbers in [0, 1], got 'red'"),
    (["train", "S", "--out", "O", "--augment", "examined", "--refiner", "none", "--examiner", "shipped"],
     "trioman train: error: --examiner: chooses among refined candidates; --refiner none gives the aligned kind"),
    (["train", "S", "--out", "O", "--augment", "aligned", "--threshold", "0.5"],
     "trioman train: error: --threshold: needs --augment examined"),
    (["train", "S", "--out", "O", "--augment", "--augment-start", "1"],
     "trioman train: error: --augment-start: must lie in [0, 1), got 1.0"),
    (["train", "S", "--out", "O", "--augment-pool", "4"],
     "trioman train: error: --augment-pool: needs --augment"),
    (["bench", "ablation", "--augment-pool", "0"],
     "trioman bench: error: --augment-pool: must be an integer >= 1, got 0"),
    (["bench", "ablation", "--baseline-frames", "all,subset"],
     "trioman bench: error: --baseline-frames: ablation trains on one corpus variant, 'all' or 'subset', got 'all,subset'"),
])
def test_the_commands_show_flags(argv, shown, capsys):
    assert main(argv) == 1
    assert capsys.readouterr().err.strip() == shown


def test_the_library_names_parameters():
    from trioman.runtime.animate import check_size, check_video_size, parse_background
    from trioman.runtime.shards import Shard

    with pytest.raises(ValueError, match=r"^size: must lie in \[16, 4096\] pixels, got 8$"):
        check_size(8)
    with pytest.raises(ValueError, match=r"^size: 17 is odd"):
        check_video_size(17)
    with pytest.raises(ValueError, match=r"^background: expected r,g,b numbers"):
        parse_background("red")
    with pytest.raises(ValueError, match=r"^shard: expected I/N with 0 <= I < N, got 2/2$"):
        Shard(2, 2)


def test_the_training_library_names_fields():
    pytest.importorskip("torch")
    from trioman.bench.ablation import AblationBenchConfig
    from trioman.toolkit.distributed import check_device
    from trioman.toolkit.train.augmentation import AugmentConfig

    with pytest.raises(ValueError, match=r"^examiner: `mode` refined does not use an Examiner"):
        AugmentConfig(mode="refined", refiner="r", examiner="e")
    with pytest.raises(ValueError, match=r"^threshold: needs `mode` examined"):
        AugmentConfig(mode="aligned", threshold=0.5)
    with pytest.raises(ValueError, match=r"^device: expected one of"):
        check_device("tpu")
    with pytest.raises(ValueError, match=r"^baseline_frames: ablation trains on one corpus variant"):
        AblationBenchConfig(baseline_frames="all,subset")
