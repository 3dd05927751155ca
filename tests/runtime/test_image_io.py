"""Image and video I/O: PNG round trips, colour order, errors naming the path, videos."""

from __future__ import annotations

import os

import cv2
import numpy as np
import pytest

from trioman.runtime import image_io
from trioman.runtime.image_io import VideoWriter, png_header, read_png, to_uint8, write_png, write_video

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
