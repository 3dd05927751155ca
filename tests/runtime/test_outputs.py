"""Atomic writes and the folder rule (runtime/outputs.py): what a command may write, replace, remove and read."""

from __future__ import annotations

import json
import os
import re

import numpy as np
import pytest

from trioman.runtime import outputs
from trioman.runtime.image_io import read_png, write_png
from trioman.runtime.outputs import atomic_folder, atomic_path, atomic_write_text, write_synced


def test_atomic_path_success_and_failure(tmp_path):
    target = tmp_path / "data.txt"
    atomic_write_text(target, "old")
    with pytest.raises(RuntimeError, match="boom"):
        with atomic_path(target) as tmp:
            assert tmp.parent == tmp_path and tmp.suffix == ".txt" and tmp != target
            tmp.write_text("half-written")
            raise RuntimeError("boom")
    assert target.read_text() == "old"
    assert os.listdir(tmp_path) == ["data.txt"]
    with atomic_path(target) as tmp:
        tmp.write_text("new")
        assert target.read_text() == "old"  # readers see the old file until the rename
    assert target.read_text() == "new"
    assert os.listdir(tmp_path) == ["data.txt"]
    # created like open(): permissions follow the umask, not mkstemp's 0o600
    umask = os.umask(0)
    os.umask(umask)
    assert target.stat().st_mode & 0o777 == 0o666 & ~umask


def test_atomic_folder_success_failure_and_overwrite(tmp_path):
    target = tmp_path / "deep" / "out"
    with pytest.raises(RuntimeError, match="boom"):
        with atomic_folder(target) as tmp:
            assert tmp.parent == target.parent and outputs.is_temp_name(tmp.name)
            write_synced(tmp / "a.bin", b"half")
            raise RuntimeError("boom")
    assert os.listdir(tmp_path / "deep") == []  # nothing half-written, no temporary folder
    with atomic_folder(target) as tmp:
        (tmp / "sub").mkdir()
        write_synced(tmp / "sub" / "a.npz", lambda f: np.savez(f, x=np.arange(3)))
        write_synced(tmp / "m.json", b"{}")
        assert not target.exists()  # readers see nothing until the rename
    assert np.load(target / "sub" / "a.npz")["x"].tolist() == [0, 1, 2]
    with pytest.raises(FileExistsError, match=r"out: folder exists and is not empty \(choose another"):
        with atomic_folder(target, overwrite=True):  # no kind: nothing is recognised, nothing replaced
            pass
    kind = outputs.FolderKind("test", "m.json", files=("m.json", "b.bin"), folders=(("sub", ("*.npz",)),))
    with pytest.raises(FileExistsError, match=r"out: folder exists and is not empty \(give `overwrite` to replace it\)"):
        with atomic_folder(target, kind=kind):
            pass
    with atomic_folder(target, overwrite=True, kind=kind) as tmp:
        write_synced(tmp / "b.bin", b"new")
    assert os.listdir(target) == ["b.bin"] and os.listdir(tmp_path / "deep") == ["out"]
    with pytest.raises(FileExistsError, match="late: folder exists and is not empty"):  # appeared while writing
        with atomic_folder(tmp_path / "late") as tmp:
            (tmp_path / "late").mkdir()
            (tmp_path / "late" / "x").write_text("x")
    assert sorted(os.listdir(tmp_path)) == ["deep", "late"]
    (tmp_path / "file").write_text("x")
    with pytest.raises(FileExistsError, match="file: exists and is not a folder"):
        with atomic_folder(tmp_path / "file", overwrite=True):
            pass
    with pytest.raises(OSError, match="missing"):  # an OSError of a write names the file
        write_synced(tmp_path / "missing" / "a.bin", b"x")


def test_write_png_failure_keeps_old_file(tmp_path, monkeypatch):
    target = tmp_path / "a.png"
    write_png(target, np.zeros((2, 3)))

    def fail(*args):
        raise OSError("disk full")

    monkeypatch.setattr(outputs.os, "replace", fail)
    with pytest.raises(OSError, match="disk full"):
        write_png(target, np.ones((2, 3)))
    monkeypatch.undo()
    np.testing.assert_array_equal(read_png(target), np.zeros((2, 3)))
    assert os.listdir(tmp_path) == ["a.png"]


# ------------------------------------------------------------------------------------------------
# video


def test_temporary_names_have_one_pattern_and_only_they_are_removed(tmp_path):
    # issue 18, case 4: what a kill -9 leaves behind carries one recognisable pattern
    made = [outputs.temp_sibling(tmp_path / n, s) for n, s in (("a.png", ".png"), ("frames.npz", ".npz"), ("run", ""),
                                                                ("subject", ".old"))]
    assert all(outputs.is_temp_name(p.name) for p in made)
    assert not any(outputs.is_temp_name(n) for n in ("a.png", ".a.png", ".a.png.tmp.png", ".a.png.0123abcz.tmp.png",
                                                      "notes.tmp", ".hidden"))
    (tmp_path / "masks").mkdir()
    stray = [outputs.temp_sibling(tmp_path / "masks" / "000001.png", ".png"), outputs.temp_sibling(tmp_path / "subject")]
    stray[0].write_bytes(b"half")
    stray[1].mkdir()
    (stray[1] / "frames.npz").write_bytes(b"half")
    keep = [tmp_path / "masks" / "000001.png", tmp_path / ".hidden", tmp_path / "notes.tmp"]
    for p in keep:
        p.write_bytes(b"mine")
    assert outputs.remove_temp_files(tmp_path) == sorted(stray)
    assert all(p.exists() for p in keep) and not any(p.exists() for p in stray)


SUBJECTISH = outputs.FolderKind("thing", "thing.json", files=("thing.json", "data.npz"), folders=(("images", ("*.png",)),))


def _folder(root, files):
    for name in files:
        (root / name).parent.mkdir(parents=True, exist_ok=True)
        (root / name).write_text("x")
    return root


@pytest.mark.parametrize("files, foreign, why", [
    (["thesis.txt", "z.png"], "thesis.txt", "the folder holds no thing.json: not a trioman thing folder"),
    (["frames/0.png", "cameras.txt"], "cameras.txt", "the folder holds no thing.json"),
    (["thing.json", "data.npz", "notes.md"], "notes.md", "not part of a trioman thing folder"),
    (["thing.json", "images/0.png", "images/raw.jpg"], "images/raw.jpg", "not part of a trioman thing folder"),
    (["thing.json", "images/deep/0.png"], "images/deep", "not part of a trioman thing folder"),
], ids=["no-marker", "capture", "extra-file", "extra-frame", "nested"])
def test_overwrite_replaces_only_a_folder_of_its_own_kind(tmp_path, files, foreign, why):
    out = _folder(tmp_path / "out", files)
    before = sorted(str(p.relative_to(out)) for p in out.rglob("*"))
    with pytest.raises(FileExistsError, match=rf"^overwrite: {out / foreign} was not written by trioman \({why}"):
        with atomic_folder(out, overwrite=True, kind=SUBJECTISH) as tmp:
            write_synced(tmp / "thing.json", b"{}")
    with pytest.raises(FileExistsError, match=rf"holds {out / foreign}, which trioman did not write"):
        outputs.check_folder_target(out, False, SUBJECTISH)
    assert sorted(str(p.relative_to(out)) for p in out.rglob("*")) == before  # nothing removed
    assert sorted(os.listdir(tmp_path)) == ["out"]  # no temporary folder left


def test_overwrite_replaces_its_own_kind_with_temporary_leftovers(tmp_path):
    out = _folder(tmp_path / "out", ["thing.json", "data.npz", "images/0.png", "images/.0.png.0123abcd.tmp.png",
                                     ".data.npz.89abcdef.tmp.npz"])
    with atomic_folder(out, overwrite=True, kind=SUBJECTISH) as tmp:
        write_synced(tmp / "thing.json", b"{}")
    assert os.listdir(out) == ["thing.json"]


@pytest.mark.parametrize("out, given, word", [
    ("in", "in", "is the input"), ("parent", "parent/in", "holds the input"), ("in/out", "in", "lies inside the input")])
def test_an_output_folder_is_never_its_own_input(tmp_path, out, given, word):
    _folder(tmp_path / "parent" / "in", ["thing.json"])
    _folder(tmp_path / "in", ["thing.json", "data.npz"])
    with pytest.raises(ValueError, match=rf"{tmp_path / out}: {word} {tmp_path / given}"):
        with atomic_folder(tmp_path / out, overwrite=True, kind=SUBJECTISH, inputs=[None, tmp_path / given]):
            pass
    assert (tmp_path / given / "thing.json").is_file() and not (tmp_path / "in" / "out").exists()


def test_atomic_folder_removes_what_an_interrupted_write_of_the_same_output_left(tmp_path):
    # issue 41, L1: a kill -9 during `export avatar` left `.OUT.xxxxxxxx.tmp/` beside the output for ever
    from trioman.runtime.outputs import atomic_folder

    left = tmp_path / ".out.0123abcd.tmp"
    left.mkdir()
    (left / "gaussians.npz").write_bytes(b"half")
    kept = [tmp_path / ".other.0123abcd.tmp", tmp_path / ".out.0123abcd.tmp.old", tmp_path / "out.0123abcd.tmp"]
    for p in kept:  # another output's, an old output kept by an interrupted swap, a user's folder
        p.mkdir()
    with atomic_folder(tmp_path / "out") as tmp:
        (tmp / "a.txt").write_text("new")
    assert not left.exists() and all(p.is_dir() for p in kept)
    assert (tmp_path / "out" / "a.txt").read_text() == "new"


def _marked(folder, kind):
    """``folder`` with ``kind``'s marker, as trioman writes it (its JSON format)."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / kind.marker).write_text(json.dumps({"format": kind.format}))
    return folder


@pytest.mark.parametrize("out", ["subject/images/000000.png", "subject/extra", "avatar/gaussians.npz", "link/x.png"])
def test_no_output_goes_inside_a_folder_trioman_wrote(tmp_path, out):
    # issue 41, D2: `render --out SUBJECT/images/000000.png` replaced a real frame of a subject it did not read
    from trioman.runtime.formats.avatar import AVATAR_FOLDER
    from trioman.runtime.formats.subject import SUBJECT_FOLDER

    _marked(_folder(tmp_path / "subject", ["images/000000.png"]), SUBJECT_FOLDER)
    _marked(_folder(tmp_path / "avatar", []), AVATAR_FOLDER)
    _folder(tmp_path / "other", ["subject.json"])  # another program's file of that name: not a subject folder
    (tmp_path / "link").symlink_to(tmp_path / "subject" / "images")  # a link is followed before the check
    folder = "avatar" if out.startswith("avatar") else "subject"  # the link leads into the subject
    with pytest.raises(ValueError, match=rf"^{tmp_path / out}: lies inside {tmp_path / folder}, a trioman {folder} folder"):
        outputs.check_not_input(tmp_path / out, [])
    outputs.check_not_input(tmp_path / "elsewhere" / "x.png", [])  # beside them: fine
    outputs.check_not_input(tmp_path / "other" / "x.png", [])


def test_a_refused_folder_of_another_kind_is_named_for_its_kind(tmp_path):
    # issue 41, U1: "was not written by trioman" was said of trioman's own outputs of another kind
    from trioman.runtime.formats.avatar import AVATAR_FOLDER
    from trioman.runtime.formats.subject import SUBJECT_FOLDER

    avatar = _marked(_folder(tmp_path / "avatar", ["gaussians.npz"]), AVATAR_FOLDER)
    with pytest.raises(FileExistsError, match=r"it is a trioman avatar folder \(avatar.json\), not a subject folder"):
        outputs.check_folder_target(avatar, True, SUBJECT_FOLDER)
    with pytest.raises(FileExistsError, match=r"folder exists and is not empty \(a trioman avatar folder\)"):
        outputs.check_folder_target(avatar, False)
    assert outputs.kind_of(avatar) is AVATAR_FOLDER and outputs.kind_of(tmp_path) is None


def test_remove_own_removes_an_earlier_output_of_its_kind_and_nothing_else(tmp_path):
    # issue 41: the demo and the benchmarks removed fixed sub-folders of OUT with no look at what they held
    own = _folder(tmp_path / "own", ["thing.json", "data.npz", "images/0.png"])
    outputs.remove_own(own, SUBJECTISH)
    assert not own.exists()
    outputs.remove_own(tmp_path / "absent", SUBJECTISH)  # nothing there: nothing to do
    mixed = _folder(tmp_path / "mixed", ["thing.json", "images/0.png", "thesis.tex"])
    with pytest.raises(FileExistsError, match=rf"{mixed / 'thesis.tex'} was not written by trioman"):
        outputs.remove_own(mixed, SUBJECTISH)
    assert sorted(p.name for p in mixed.rglob("*")) == ["0.png", "images", "thesis.tex", "thing.json"]
    (tmp_path / "link").symlink_to(_folder(tmp_path / "elsewhere", ["thing.json"]))
    with pytest.raises(FileExistsError, match="is a link"):
        outputs.remove_own(tmp_path / "link", SUBJECTISH)
    assert (tmp_path / "elsewhere" / "thing.json").is_file()


def test_a_folder_pattern_of_a_kind_matches_its_sub_folders(tmp_path):
    kind = outputs.FolderKind("run", "run.json", files=("run.json",), folders=(("eval_*", ("*.csv",)),))
    assert kind.first_foreign(_folder(tmp_path / "a", ["run.json", "eval_test/m.csv", "eval_x_0000010/m.csv"])) is None
    b = _folder(tmp_path / "b", ["run.json", "evaluation/m.csv"])
    assert kind.first_foreign(b) == b / "evaluation"


@pytest.mark.parametrize("make, said", [
    (lambda p: os.mkfifo(p), "not a regular file (a FIFO, socket or device)"),
    (lambda p: os.symlink("/dev/zero", p), "not a regular file (a FIFO, socket or device)"),
    (lambda p: os.mkdir(p), "a folder, not a file"),
    (lambda p: os.symlink(p.parent / "gone", p), "a broken link"),
], ids=["fifo", "dev-zero", "folder", "broken-link"])
def test_what_is_there_instead_of_a_file_is_said(tmp_path, make, said):
    # issue 41, U5: a FIFO or a link to /dev/zero was reported as a "missing file" (and a FIFO read would block)
    from trioman.runtime.formats.common import FormatError, load_npz, read_json

    path = tmp_path / "x"
    make(path)
    assert outputs.not_a_file(path) == said
    for read in (read_json, load_npz):
        with pytest.raises(FormatError, match=rf"^{path}: {re.escape(said)}$"):
            read(path)
    with pytest.raises(ValueError, match=rf"^{path}: {re.escape(said)}$"):
        read_png(path)
    assert outputs.not_a_file(tmp_path / "absent") == "missing file"


def test_a_process_lock_refuses_a_second_holder_and_ignores_a_killed_ones_file(tmp_path):
    lock = tmp_path / "sub" / ".out.lock"
    with outputs.process_lock(lock, "out: another run into out"):
        held = json.loads(lock.read_text())
        assert held["pid"] == os.getpid()
        with pytest.raises(ValueError, match=rf"^out: another run into out is running \(pid {os.getpid()} since .*; lock {lock}\)"):
            with outputs.process_lock(lock, "out: another run into out"):
                pass
    assert not lock.exists()
    lock.write_text("left by kill -9")  # nobody holds it: the system released the killed holder's lock
    with outputs.process_lock(lock, "out: another run into out"):
        assert json.loads(lock.read_text())["pid"] == os.getpid()
    assert not lock.exists()
