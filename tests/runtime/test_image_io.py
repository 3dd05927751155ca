"""Image and video I/O: PNG round trips, colour order, errors naming the path, atomic writes."""

from __future__ import annotations

import json
import os
import re

import cv2
import numpy as np
import pytest

from trioman.runtime import image_io
from trioman.runtime.image_io import (
    VideoWriter,
    atomic_folder,
    atomic_path,
    atomic_write_text,
    write_synced,
    png_header,
    read_png,
    to_uint8,
    write_png,
    write_video,
)


def q8(img: np.ndarray) -> np.ndarray:
    """The value a float image reads back as after 8-bit quantisation."""
    return (np.rint(np.clip(img, 0, 1) * 255) / np.float32(255)).astype(np.float32)


def test_png_round_trip_rgb(tmp_path):
    img = np.random.default_rng(0).random((12, 16, 3), dtype=np.float32)
    write_png(tmp_path / "a.png", img)
    back = read_png(tmp_path / "a.png")
    assert back.dtype == np.float32 and back.shape == (12, 16, 3)
    np.testing.assert_array_equal(back, q8(img))
    assert png_header(tmp_path / "a.png") == (16, 12, 3)
    assert sorted(os.listdir(tmp_path)) == ["a.png"]


def test_png_round_trip_gray_and_modes(tmp_path):
    img = np.linspace(0, 1, 12 * 16, dtype=np.float32).reshape(12, 16)
    write_png(tmp_path / "g.png", img)
    assert png_header(tmp_path / "g.png") == (16, 12, 1)
    np.testing.assert_array_equal(read_png(tmp_path / "g.png"), q8(img))
    rgb = read_png(tmp_path / "g.png", mode="rgb")
    assert rgb.shape == (12, 16, 3)
    np.testing.assert_array_equal(rgb[..., 1], q8(img))
    write_png(tmp_path / "c.png", np.dstack([img, img, img]))
    np.testing.assert_allclose(read_png(tmp_path / "c.png", mode="gray"), q8(img), atol=1 / 255)
    with pytest.raises(ValueError, match="mode"):
        read_png(tmp_path / "g.png", mode="bgr")


def test_png_is_rgb_on_disk(tmp_path):
    """Red in numpy is red in the file: OpenCV's BGR order is handled inside image_io."""
    img = np.zeros((4, 5, 3), np.float32)
    img[..., 0] = 1.0
    write_png(tmp_path / "red.png", img)
    raw = cv2.imread(str(tmp_path / "red.png"), cv2.IMREAD_UNCHANGED)  # BGR
    assert raw.dtype == np.uint8 and (raw[..., 2] == 255).all() and (raw[..., :2] == 0).all()
    np.testing.assert_array_equal(read_png(tmp_path / "red.png")[0, 0], [1, 0, 0])


def test_png_clips_and_rounds(tmp_path):
    img = np.array([[-0.5, 0.0, 0.5 / 255, 0.7 / 255, 1.0, 3.0]], np.float32)
    write_png(tmp_path / "c.png", img)
    u8 = cv2.imread(str(tmp_path / "c.png"), cv2.IMREAD_UNCHANGED)
    assert u8.tolist() == [[0, 0, 0, 1, 255, 255]] or u8.tolist() == [[0, 0, 1, 1, 255, 255]]
    assert to_uint8(np.array([True, False])).tolist() == [255, 0]
    assert to_uint8(np.array([7], np.uint8)).tolist() == [7]


def test_read_png_rgba_and_16bit(tmp_path):
    bgra = np.zeros((3, 4, 4), np.uint8)
    bgra[..., 0] = 255  # blue
    bgra[..., 3] = 128
    cv2.imwrite(str(tmp_path / "rgba.png"), bgra)
    assert png_header(tmp_path / "rgba.png") == (4, 3, 4)
    np.testing.assert_array_equal(read_png(tmp_path / "rgba.png")[0, 0], [0, 0, 1])
    g16 = np.full((3, 4), 65535, np.uint16)
    cv2.imwrite(str(tmp_path / "g16.png"), g16)
    np.testing.assert_array_equal(read_png(tmp_path / "g16.png"), np.ones((3, 4), np.float32))


@pytest.mark.parametrize(
    "img, match",
    [
        (np.full((4, 4, 3), np.nan, np.float32), r"bad\.png: 48 non-finite value\(s\) \(NaN/Inf\)"),
        (np.zeros((4, 4, 4), np.float32), r"bad\.png: expected shape \[H, W, 3\] \(RGB\) or \[H, W\] \(gray\), got \[4, 4, 4\]"),
        (np.zeros((4,), np.float32), r"bad\.png: expected shape"),
        (np.zeros((4, 4), np.int64), r"bad\.png: expected a float image in \[0, 1\] \(or uint8\), got dtype int64"),
    ],
)
def test_write_png_rejects(tmp_path, img, match):
    with pytest.raises(ValueError, match=match):
        write_png(tmp_path / "bad.png", img)
    assert os.listdir(tmp_path) == []


def test_read_png_errors_name_the_path(tmp_path):
    with pytest.raises(FileNotFoundError, match=r"missing\.png: image file not found"):
        read_png(tmp_path / "missing.png")
    (tmp_path / "broken.png").write_bytes(b"\x89PNG\r\n\x1a\n garbage garbage")
    with pytest.raises(ValueError, match=r"broken\.png: not a readable image"):
        read_png(tmp_path / "broken.png")
    (tmp_path / "empty.png").write_bytes(b"")
    with pytest.raises(ValueError, match=r"empty\.png: not a readable image"):
        read_png(tmp_path / "empty.png")
    with pytest.raises(ValueError, match=r"broken\.png: not a PNG file"):
        png_header(tmp_path / "broken.png")
    with pytest.raises(FileNotFoundError, match=r"missing\.png: image file not found"):
        png_header(tmp_path / "missing.png")



def _damaged_pngs(tmp_path):
    write_png(tmp_path / "whole.png", np.random.default_rng(0).random((32, 32, 3), dtype=np.float32))
    data = (tmp_path / "whole.png").read_bytes()
    (tmp_path / "half.png").write_bytes(data[:len(data) // 2])
    (tmp_path / "no_iend.png").write_bytes(data[:-12])
    flipped = bytearray(data)
    flipped[60:80] = bytes(b ^ 0xFF for b in flipped[60:80])
    (tmp_path / "flipped.png").write_bytes(bytes(flipped))
    return {"half.png": "truncated PNG: chunk 'IDAT'", "no_iend.png": "truncated PNG: no IEND",
            "flipped.png": "corrupt PNG: chunk 'IDAT' at byte 33 fails its CRC"}


def test_a_damaged_png_is_one_line_and_opencv_says_nothing(tmp_path, capfd):
    """Issue 26 (minor): a truncated PNG printed OpenCV's '[ WARN ]' and libpng's line before the error."""
    for name, why in _damaged_pngs(tmp_path).items():
        with pytest.raises(ValueError) as err:
            read_png(tmp_path / name)
        assert str(err.value).startswith(f"{tmp_path / name}: not a readable image (")
        assert why in str(err.value) and "\n" not in str(err.value)
    assert read_png(tmp_path / "whole.png").shape == (32, 32, 3)
    out, errs = capfd.readouterr()
    assert out == "" and errs == ""


def test_opencv_is_quiet_while_it_decodes(tmp_path, capfd, monkeypatch):
    """The decoder's own warnings are silenced too, for damage the chunk check does not see."""
    _damaged_pngs(tmp_path)
    level = cv2.utils.logging.getLogLevel()
    monkeypatch.setattr(image_io, "_png_damage", lambda data: None)
    with pytest.raises(ValueError, match=r"half\.png: not a readable image \(corrupt or unsupported"):
        read_png(tmp_path / "half.png")
    assert capfd.readouterr().err == ""
    assert cv2.utils.logging.getLogLevel() == level

def test_write_png_missing_folder(tmp_path):
    with pytest.raises(FileNotFoundError, match=r"nope"):
        write_png(tmp_path / "nope" / "a.png", np.zeros((2, 2)))


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
            assert tmp.parent == target.parent and image_io.is_temp_name(tmp.name)
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
    kind = image_io.FolderKind("test", "m.json", files=("m.json", "b.bin"), folders=(("sub", ("*.npz",)),))
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

    monkeypatch.setattr(image_io.os, "replace", fail)
    with pytest.raises(OSError, match="disk full"):
        write_png(target, np.ones((2, 3)))
    monkeypatch.undo()
    np.testing.assert_array_equal(read_png(target), np.zeros((2, 3)))
    assert os.listdir(tmp_path) == ["a.png"]


# ------------------------------------------------------------------------------------------------
# video


def _read_video(path):
    cap = cv2.VideoCapture(str(path))
    assert cap.isOpened()
    frames = []
    while True:
        ok, frame = cap.read()
        if not ok:
            break
        frames.append(frame)
    cap.release()
    return frames


def test_write_video_round_trip(tmp_path):
    colours = [(1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 1, 1), (0, 0, 0), (1, 1, 0), (0.5, 0.5, 0.5)]
    frames = (np.broadcast_to(np.array(c, np.float32), (24, 32, 3)).copy() for c in colours)
    count = write_video(tmp_path / "v.mp4", frames, fps=10)
    assert count == 7
    assert os.listdir(tmp_path) == ["v.mp4"]
    back = _read_video(tmp_path / "v.mp4")
    assert len(back) == 7
    assert back[0].shape == (24, 32, 3)
    # first frame is red: BGR read-back has a large R channel (lossy codec, loose check)
    assert back[0][..., 2].mean() > 200 and back[0][..., 0].mean() < 60
    assert back[2][..., 0].mean() > 200 and back[2][..., 2].mean() < 60


def test_video_writer_gray_frames_and_size(tmp_path):
    with VideoWriter(tmp_path / "g.mp4", fps=5, size=(32, 16)) as video:
        for v in (0.0, 0.5, 1.0):
            video.write(np.full((16, 32), v, np.float32))
    back = _read_video(tmp_path / "g.mp4")
    assert len(back) == 3 and back[0].shape == (16, 32, 3)


def test_video_exception_leaves_nothing(tmp_path):
    def frames():
        yield np.zeros((16, 16, 3), np.float32)
        yield np.zeros((16, 16, 3), np.float32)
        raise RuntimeError("render failed")

    with pytest.raises(RuntimeError, match="render failed"):
        write_video(tmp_path / "v.mp4", frames(), fps=10)
    assert os.listdir(tmp_path) == []


def test_video_errors(tmp_path):
    with pytest.raises(ValueError, match=r"v\.mp4: frame 1: expected size 16x16 \(W x H\), got 8x16"):
        write_video(tmp_path / "v.mp4", [np.zeros((16, 16, 3)), np.zeros((16, 8, 3))], fps=10)
    with pytest.raises(ValueError, match=r"v\.mp4: no frames were written"):
        write_video(tmp_path / "v.mp4", [], fps=10)
    with pytest.raises(ValueError, match=r"fps: expected a positive number, got 0.0"):
        write_video(tmp_path / "v.mp4", [np.zeros((16, 16, 3))], fps=0)
    bad = np.zeros((16, 16, 3), np.float32)
    bad[3, 4, 1] = np.inf
    with pytest.raises(ValueError, match=r"v\.mp4: frame 0: 1 non-finite"):
        write_video(tmp_path / "v.mp4", [bad], fps=10)
    with pytest.raises(FileNotFoundError, match=r"does not exist"):
        write_video(tmp_path / "nope" / "v.mp4", [np.zeros((16, 16, 3))], fps=10)
    assert os.listdir(tmp_path) == []


def test_video_writer_not_opened(tmp_path, monkeypatch):
    class Closed:
        def __init__(self, *args):
            pass

        def isOpened(self):
            return False

        def release(self):
            pass

    monkeypatch.setattr(image_io.cv2, "VideoWriter", Closed)
    with pytest.raises(ValueError, match=r"v\.mp4: OpenCV could not open a video writer \(fourcc 'mp4v', size 16x16"):
        write_video(tmp_path / "v.mp4", [np.zeros((16, 16, 3))], fps=10)
    assert os.listdir(tmp_path) == []


def test_temporary_names_have_one_pattern_and_only_they_are_removed(tmp_path):
    # issue 18, case 4: what a kill -9 leaves behind carries one recognisable pattern
    made = [image_io.temp_sibling(tmp_path / n, s) for n, s in (("a.png", ".png"), ("frames.npz", ".npz"), ("run", ""),
                                                                ("subject", ".old"))]
    assert all(image_io.is_temp_name(p.name) for p in made)
    assert not any(image_io.is_temp_name(n) for n in ("a.png", ".a.png", ".a.png.tmp.png", ".a.png.0123abcz.tmp.png",
                                                      "notes.tmp", ".hidden"))
    (tmp_path / "masks").mkdir()
    stray = [image_io.temp_sibling(tmp_path / "masks" / "000001.png", ".png"), image_io.temp_sibling(tmp_path / "subject")]
    stray[0].write_bytes(b"half")
    stray[1].mkdir()
    (stray[1] / "frames.npz").write_bytes(b"half")
    keep = [tmp_path / "masks" / "000001.png", tmp_path / ".hidden", tmp_path / "notes.tmp"]
    for p in keep:
        p.write_bytes(b"mine")
    assert image_io.remove_temp_files(tmp_path) == sorted(stray)
    assert all(p.exists() for p in keep) and not any(p.exists() for p in stray)


@pytest.mark.parametrize("w, h", [(17, 17), (257, 18), (18, 20)])
def test_a_video_keeps_odd_sides_by_padding_them(tmp_path, w, h):
    # issue 18, case 9: mp4v silently dropped an odd last row or column (257 px became 256)
    frame = np.random.default_rng(0).random((h, w, 3), dtype=np.float32)
    with image_io.VideoWriter(tmp_path / "v.mp4", fps=10) as video:
        video.write(frame)
    assert video.video_size == (w + w % 2, h + h % 2)
    cap = cv2.VideoCapture(str(tmp_path / "v.mp4"))
    ok, got = cap.read()
    cap.release()
    assert ok and got.shape == (h + h % 2, w + w % 2, 3)


SUBJECTISH = image_io.FolderKind("thing", "thing.json", files=("thing.json", "data.npz"), folders=(("images", ("*.png",)),))


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
        image_io.check_folder_target(out, False, SUBJECTISH)
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
    from trioman.runtime.image_io import atomic_folder

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
        image_io.check_not_input(tmp_path / out, [])
    image_io.check_not_input(tmp_path / "elsewhere" / "x.png", [])  # beside them: fine
    image_io.check_not_input(tmp_path / "other" / "x.png", [])


def test_a_refused_folder_of_another_kind_is_named_for_its_kind(tmp_path):
    # issue 41, U1: "was not written by trioman" was said of trioman's own outputs of another kind
    from trioman.runtime.formats.avatar import AVATAR_FOLDER
    from trioman.runtime.formats.subject import SUBJECT_FOLDER

    avatar = _marked(_folder(tmp_path / "avatar", ["gaussians.npz"]), AVATAR_FOLDER)
    with pytest.raises(FileExistsError, match=r"it is a trioman avatar folder \(avatar.json\), not a subject folder"):
        image_io.check_folder_target(avatar, True, SUBJECT_FOLDER)
    with pytest.raises(FileExistsError, match=r"folder exists and is not empty \(a trioman avatar folder\)"):
        image_io.check_folder_target(avatar, False)
    assert image_io.kind_of(avatar) is AVATAR_FOLDER and image_io.kind_of(tmp_path) is None


def test_remove_own_removes_an_earlier_output_of_its_kind_and_nothing_else(tmp_path):
    # issue 41: the demo and the benchmarks removed fixed sub-folders of OUT with no look at what they held
    own = _folder(tmp_path / "own", ["thing.json", "data.npz", "images/0.png"])
    image_io.remove_own(own, SUBJECTISH)
    assert not own.exists()
    image_io.remove_own(tmp_path / "absent", SUBJECTISH)  # nothing there: nothing to do
    mixed = _folder(tmp_path / "mixed", ["thing.json", "images/0.png", "thesis.tex"])
    with pytest.raises(FileExistsError, match=rf"{mixed / 'thesis.tex'} was not written by trioman"):
        image_io.remove_own(mixed, SUBJECTISH)
    assert sorted(p.name for p in mixed.rglob("*")) == ["0.png", "images", "thesis.tex", "thing.json"]
    (tmp_path / "link").symlink_to(_folder(tmp_path / "elsewhere", ["thing.json"]))
    with pytest.raises(FileExistsError, match="is a link"):
        image_io.remove_own(tmp_path / "link", SUBJECTISH)
    assert (tmp_path / "elsewhere" / "thing.json").is_file()


def test_a_folder_pattern_of_a_kind_matches_its_sub_folders(tmp_path):
    kind = image_io.FolderKind("run", "run.json", files=("run.json",), folders=(("eval_*", ("*.csv",)),))
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
    assert image_io.not_a_file(path) == said
    for read in (read_json, load_npz):
        with pytest.raises(FormatError, match=rf"^{path}: {re.escape(said)}$"):
            read(path)
    with pytest.raises(ValueError, match=rf"^{path}: {re.escape(said)}$"):
        read_png(path)
    assert image_io.not_a_file(tmp_path / "absent") == "missing file"
