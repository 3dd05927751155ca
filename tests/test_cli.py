"""The ``trioman`` command: every subcommand listed, runtime commands and --help work without torch."""

import pytest

from tests.conftest import run_python
from trioman.cli import COMMANDS, main


def test_help_lists_every_command_without_torch():
    proc = run_python("from trioman.cli import main; main(['--help'])", block_torch=True)
    assert proc.returncode == 0, proc.stderr
    for cmd in COMMANDS:
        assert cmd.name in proc.stdout


@pytest.mark.parametrize("cmd", [c for c in COMMANDS if c.extra == "train"], ids=lambda c: c.name)
def test_training_command_without_torch_names_the_extra(cmd, tmp_path):
    positional = {"bench": ["synth"], "train": [str(tmp_path / "subject")], "eval": [str(tmp_path / "run")],
                  "export": ["avatar", str(tmp_path / "run")], "triplets": [str(tmp_path / "run")],
                  "train-refiner": ["--corpus", str(tmp_path / "c")], "train-examiner": ["--corpus", str(tmp_path / "c")]}
    args = [cmd.name, *positional.get(cmd.name, []), "--out", str(tmp_path / "x")]
    proc = run_python(f"import sys; from trioman.cli import main; sys.exit(main({args!r}))", block_torch=True)
    assert proc.returncode == 1
    assert "pip install 'trioman[train]'" in proc.stderr and "torch" in proc.stderr
    assert "Traceback" not in proc.stderr
    assert not (tmp_path / "x").exists()


def test_no_command_prints_help(capsys):
    assert main([]) == 2
    assert "COMMAND" in capsys.readouterr().out
