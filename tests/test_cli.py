"""The ``trioman`` command: every subcommand listed, runtime commands and --help work without torch."""

import errno
import os

import pytest

from tests.conftest import run_python
from tests.full_disk import full_disk_open
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


# --------------------------------------------------------------------------------------------------
# OS errors: one line naming the path and the cause, exit 1, nothing left behind (issue 18, case 2)


@pytest.fixture
def avatar_dir(tmp_path):
    from tests.runtime.factories import write

    write(tmp_path / "avatars")
    return tmp_path / "avatars" / "a"


def render(avatar_dir, out) -> int:
    return main(["render", str(avatar_dir), "--out", str(out), "--size", "32"])


def assert_one_line(err: str, *parts: str) -> None:
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    for part in parts:
        assert part in err, (part, err)


def test_an_output_path_that_is_a_folder_is_named(avatar_dir, tmp_path, capsys):
    (tmp_path / "img.png").mkdir()
    assert render(avatar_dir, tmp_path / "img.png") == 1
    assert_one_line(capsys.readouterr().err, f"{tmp_path / 'img.png'}: is a directory")


def test_a_full_disk_names_the_file_and_leaves_nothing(avatar_dir, tmp_path, capsys, monkeypatch):
    from trioman.runtime import outputs

    monkeypatch.setattr(outputs, "open", full_disk_open, raising=False)
    out = tmp_path / "out" / "img.png"
    out.parent.mkdir()
    assert render(avatar_dir, out) == 1
    assert_one_line(capsys.readouterr().err, f"{out}: no space left on the device")
    assert list(out.parent.iterdir()) == []  # no partial file, no temporary file


@pytest.mark.parametrize("code, cause", [(errno.EROFS, "read-only file system"), (errno.EACCES, "permission denied")])
def test_an_unwritable_folder_names_the_file(avatar_dir, tmp_path, capsys, monkeypatch, code, cause):
    real_open = os.open

    def refuse_create(path, flags, *args):  # the tests run as root, which chmod cannot stop
        if flags & os.O_CREAT:
            raise OSError(code, os.strerror(code), path)
        return real_open(path, flags, *args)

    monkeypatch.setattr(os, "open", refuse_create)
    out = tmp_path / "img.png"
    assert render(avatar_dir, out) == 1
    assert_one_line(capsys.readouterr().err, f"{out}: {cause}")
    assert not out.exists()


def test_describe_os_error():
    from trioman.cli import describe_os_error

    assert describe_os_error(OSError(errno.ENOSPC, "No space left on device", "/d/f")) == \
        "/d/f: no space left on the device (the disk is full)"
    assert describe_os_error(OSError(errno.EXDEV, "Invalid cross-device link", "/a", None, "/b")) == \
        "/a -> /b: Invalid cross-device link"
    assert describe_os_error(FileNotFoundError("run: no checkpoint")) == "run: no checkpoint"


def test_a_broken_torch_install_is_one_line_naming_the_extra():
    # issue 41, D14: when `import torch` itself fails, training commands printed a raw traceback
    r = run_python("""
        import importlib.abc, importlib.machinery, sys

        class Broken(importlib.abc.MetaPathFinder, importlib.abc.Loader):
            def find_spec(self, name, path=None, target=None):
                return importlib.machinery.ModuleSpec(name, self) if name == "torch" else None
            def create_module(self, spec):
                return None
            def exec_module(self, module):
                raise OSError("libtorch_cpu.so: cannot open shared object file: No such file or directory")

        sys.meta_path.insert(0, Broken())
        from trioman.cli import main
        sys.exit(main(["train", "SUBJECT", "--out", "RUN"]))
    """)
    assert r.returncode == 1, r.stderr
    assert r.stderr.strip() == ("trioman train: error: 'trioman train' needs the 'train' extra, and torch is installed but "
                                "fails to import (OSError: libtorch_cpu.so: cannot open shared object file: No such file "
                                "or directory): reinstall it, pip install 'trioman[train]' (CPU torch: pip install "
                                "torch==2.13.0 first)"), r.stderr
