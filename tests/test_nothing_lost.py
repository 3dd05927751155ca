"""Issue 41: no command writes over, into or around what it reads, nor into another trioman output, nor replaces a
folder that is not its own kind. Every command that writes, with its output placed on each of its inputs' roles
(equal to, inside, holding the input; inside another output; a foreign folder; the wrong kind with --overwrite):
the command is refused with one line, and nothing anywhere in the work folder changes."""

from __future__ import annotations

import hashlib
import os
import shutil
from pathlib import Path

import pytest

pytest.importorskip("torch")
pytest.importorskip("anny")

from trioman.cli import main  # noqa: E402


@pytest.fixture(scope="module")
def made(tmp_path_factory) -> Path:
    """A tiny subject S, a run R trained on it, its avatar A, an augment output G and a foreign folder F."""
    root = tmp_path_factory.mktemp("made")
    assert main(["synth", "--out", str(root / "S"), "--size", "32", "--frames", "6", "--quiet"]) == 0
    assert main(["train", str(root / "S"), "--out", str(root / "R"), "--iterations", "1", "--quiet"]) == 0
    assert main(["export", "avatar", str(root / "R"), "--out", str(root / "A")]) == 0
    assert main(["augment", str(root / "S"), "--avatar", str(root / "A"), "--out", str(root / "G"), "--limit", "1",
                 "--quiet"]) == 0
    (root / "F").mkdir()
    (root / "F" / "thesis.tex").write_text("a user's own work")
    return root


def _snapshot(root: Path) -> dict[str, str]:
    files = {}
    for folder, dirs, names in os.walk(root):
        for name in dirs + names:
            p = Path(folder) / name
            rel = str(p.relative_to(root))
            if p.is_symlink():
                files[rel] = "link:" + os.readlink(p)
            elif p.is_file():
                files[rel] = hashlib.sha256(p.read_bytes()).hexdigest()
            else:
                files[rel] = "folder"
    return files


# (id, argv with the work folder's names; {out} is the output under test, relative to the work folder)
CASES = [
    ("render-into-avatar", ["render", "A", "--out", "A/gaussians.npz"]),
    ("render-into-subject", ["render", "A", "--out", "S/images/000000.png"]),
    ("render-into-augment-output", ["render", "A", "--out", "G/images/x.png"]),
    ("animate-into-avatar", ["animate", "A", "--motion", "walk", "--out", "A/walk.mp4"]),
    ("animate-frames-into-subject", ["animate", "A", "--motion", "walk", "--out", "w.mp4", "--frames-dir", "S/images"]),
    ("animate-frames-on-subject", ["animate", "A", "--motion", "S", "--out", "w.mp4", "--frames-dir", "S"]),
    ("augment-on-its-subject", ["augment", "S", "--avatar", "A", "--out", "S", "--overwrite"]),
    ("augment-on-its-own-input-output", ["augment", "G", "--avatar", "A", "--out", "G", "--overwrite"]),
    ("augment-inside-subject", ["augment", "S", "--avatar", "A", "--out", "S/aug"]),
    ("augment-inside-avatar", ["augment", "S", "--avatar", "A", "--out", "A/aug"]),
    ("augment-holding-inputs", ["augment", "S", "--avatar", "A", "--out", ".", "--overwrite"]),
    ("augment-over-foreign", ["augment", "S", "--avatar", "A", "--out", "F", "--overwrite"]),
    ("augment-over-avatar-kind", ["augment", "G", "--avatar", "A", "--out", "R", "--overwrite"]),
    ("train-on-subject", ["train", "S", "--out", "S"]),
    ("train-inside-subject", ["train", "S", "--out", "S/run"]),
    ("train-holding-subject", ["train", "S", "--out", "."]),
    ("train-into-avatar", ["train", "S", "--out", "A"]),
    ("train-into-foreign", ["train", "S", "--out", "F"]),
    ("train-inside-augment-output", ["train", "S", "--out", "G/run"]),
    ("export-avatar-into-run", ["export", "avatar", "R", "--out", "R/avatar"]),
    ("export-avatar-over-subject", ["export", "avatar", "R", "--out", "S", "--overwrite"]),
    ("export-avatar-over-foreign", ["export", "avatar", "R", "--out", "F", "--overwrite"]),
    ("export-avatar-inside-subject", ["export", "avatar", "R", "--out", "S/avatar"]),
    ("synth-over-avatar", ["synth", "--out", "A", "--size", "32", "--frames", "6", "--overwrite"]),
    ("synth-over-foreign", ["synth", "--out", "F", "--size", "32", "--frames", "6", "--overwrite"]),
    ("synth-inside-avatar", ["synth", "--out", "A/s", "--size", "32", "--frames", "6"]),
    ("triplets-inside-subject", ["triplets", "R", "--out", "S/t.npz"]),
    ("eval-into-subject", ["eval", "R", "--out", "S", "--no-video"]),
    ("fit-inside-its-frames", ["fit", "S/images", "--out", "S/images/fit"]),
    ("fit-into-avatar", ["fit", "S/images", "--out", "A/fit"]),
]


@pytest.mark.parametrize("argv", [c[1] for c in CASES], ids=[c[0] for c in CASES])
def test_no_command_writes_over_into_or_around_what_it_must_not(made, tmp_path, argv, capsys, monkeypatch):
    work = tmp_path / "work"
    shutil.copytree(made, work, symlinks=True)
    monkeypatch.chdir(work)
    before = _snapshot(tmp_path)
    capsys.readouterr()
    assert main(argv + (["--quiet"] if argv[0] in ("augment", "train", "fit", "eval", "triplets", "synth") else [])) == 1
    err = capsys.readouterr().err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    assert _snapshot(tmp_path) == before, err  # nothing written, replaced or removed anywhere
