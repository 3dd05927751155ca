"""The frame reader of ``trioman fit``: selections, folders, videos, rotation, damaged input, laziness.

The videos are tiny mp4v files written here. Each frame carries its index in binary (bottom half: 8 black or
white stripes) under a fixed pattern (top half: red left, blue right), so a frame read back says which it is.
"""

from __future__ import annotations

import struct
import time
import tracemalloc
from collections import Counter
from pathlib import Path

import cv2
import numpy as np
import pytest

from tests.conftest import run_python
from trioman.runtime import video_input
from trioman.runtime.video_input import MAX_SIDE, FrameSelection, VideoInfo, open_frames

W, H = 64, 48
REAL_CAPTURE = cv2.VideoCapture


def frame_rgb(index: int, w: int = W, h: int = H) -> np.ndarray:
    """uint8 RGB [h, w, 3]: top half red | blue, bottom half the bits of ``index % 256`` (stripe k: bit k)."""
    img = np.zeros((h, w, 3), np.uint8)
    img[: h // 2, : w // 2] = (255, 0, 0)
    img[: h // 2, w // 2:] = (0, 0, 255)
    for k in range(8):
        img[h // 2:, k * w // 8:(k + 1) * w // 8] = 255 * (index >> k & 1)
    return img


def index_of(frame: np.ndarray) -> int:
    """The index (mod 256) a frame of ``frame_rgb`` carries, at any size: the middle of each stripe."""
    h, w = frame.shape[:2]
    stripes = [frame[h * 5 // 8:h * 7 // 8, k * w // 8 + w // 32:(k + 1) * w // 8 - w // 32] for k in range(8)]
    return sum(1 << k for k, stripe in enumerate(stripes) if stripe.mean() > 128)


def write_video(path: Path, frames: list[np.ndarray], fps: float = 25.0, fourcc: str = "mp4v") -> Path:
    h, w = frames[0].shape[:2]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc), fps, (w, h))
    assert writer.isOpened()
    for frame in frames:
        writer.write(cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
    writer.release()
    return path


def index_video(path: Path, count: int = 30, fourcc: str = "mp4v") -> Path:
    return write_video(path, [frame_rgb(i) for i in range(count)], fourcc=fourcc)


def write_image(path: Path, rgb: np.ndarray) -> Path:
    assert cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    return path


def index_folder(folder: Path, count: int = 30) -> Path:
    folder.mkdir()
    for i in range(count):
        write_image(folder / f"f{i}.png", frame_rgb(i))
    return folder


def set_rotation(path: Path, degrees: int) -> None:
    """Write the rotation matrix a phone writes into the video track's tkhd box (MP4 from OpenCV: moov at the end)."""
    data = bytearray(path.read_bytes())

    def boxes(start: int, end: int):
        while start + 8 <= end:
            size, kind = struct.unpack(">I4s", data[start:start + 8])
            yield kind, start, start + size
            start += size

    moov = next((s, e) for k, s, e in boxes(0, len(data)) if k == b"moov")
    trak = next((s, e) for k, s, e in boxes(moov[0] + 8, moov[1]) if k == b"trak")
    tkhd = next(s for k, s, e in boxes(trak[0] + 8, trak[1]) if k == b"tkhd")
    assert data[tkhd + 8] == 0  # version 0: 32-bit times
    matrix = tkhd + 8 + 4 + 20 + 8 + 8  # version/flags, times/id/duration, reserved, layer/group/volume
    w, h = (v >> 16 for v in struct.unpack(">II", data[matrix + 36:matrix + 44]))
    a, b, c, d, tx, ty = {90: (0, 1, -1, 0, h, 0), 180: (-1, 0, 0, -1, w, h), 270: (0, -1, 1, 0, 0, w)}[degrees]
    data[matrix:matrix + 36] = struct.pack(">9i", a << 16, b << 16, 0, c << 16, d << 16, 0, tx << 16, ty << 16, 1 << 30)
    path.write_bytes(bytes(data))


class Capture:
    """cv2.VideoCapture counting grab/retrieve, with properties overridden; ``no_auto``: a build that cannot
    rotate by itself (auto-rotation off and refused)."""

    def __init__(self, cap: cv2.VideoCapture, props: dict[int, float], no_auto: bool):
        self.cap, self.props, self.no_auto, self.calls = cap, props, no_auto, Counter()
        if no_auto:
            cap.set(cv2.CAP_PROP_ORIENTATION_AUTO, 0)

    def set(self, prop: int, value: float) -> bool:
        return False if self.no_auto and prop == cv2.CAP_PROP_ORIENTATION_AUTO else self.cap.set(prop, value)

    def get(self, prop: int) -> float:
        if self.no_auto and prop == cv2.CAP_PROP_ORIENTATION_AUTO:
            return 0.0
        return self.props[prop] if prop in self.props else self.cap.get(prop)

    def grab(self) -> bool:
        self.calls["grab"] += 1
        return self.cap.grab()

    def retrieve(self):
        self.calls["retrieve"] += 1
        return self.cap.retrieve()

    def __getattr__(self, name: str):
        return getattr(self.cap, name)


@pytest.fixture
def capture(monkeypatch):
    """install(props=None, no_auto=False) -> the list of the Captures the module opens from then on."""
    made: list[Capture] = []

    def install(props: dict[int, float] | None = None, no_auto: bool = False) -> list[Capture]:
        def make(*args):
            made.append(Capture(REAL_CAPTURE(*args), props or {}, no_auto))
            return made[-1]

        monkeypatch.setattr(cv2, "VideoCapture", make)
        return made

    return install


# --------------------------------------------------------------------------------------------------
# frames, names, values


def test_video_frames_names_and_values(tmp_path):
    video = index_video(tmp_path / "clip.mp4")
    info, frames = open_frames(video, FrameSelection(long_side=None))
    assert info == VideoInfo(video, "video", 25.0, 30, W, H, 0)
    frames = list(frames)
    assert [i for i, _, _ in frames] == list(range(30))
    assert [name for _, name, _ in frames] == [f"{i:06d}" for i in range(30)]
    for i, _, frame in frames:
        assert frame.dtype == np.uint8 and frame.shape == (H, W, 3) and frame.flags.c_contiguous
        assert index_of(frame) == i
        want = frame_rgb(i).astype(int)
        inner = (slice(4, H // 2 - 4), slice(4, W - 4))  # away from the edges the codec blurs
        assert np.abs(frame[inner].astype(int) - want[inner]).max() <= 12  # RGB order, codec tolerance
        assert np.abs(frame[H // 2 + 4:].astype(int) - want[H // 2 + 4:]).mean() <= 8


def test_fps_reported_as_given(tmp_path, capture):
    video = write_video(tmp_path / "ntsc.mp4", [frame_rgb(i) for i in range(3)], fps=30000 / 1001)
    assert open_frames(video)[0].fps == pytest.approx(29.97, abs=1e-3)
    for fps in (0.0, float("nan"), float("inf"), -1.0):
        capture({cv2.CAP_PROP_FPS: fps})
        assert open_frames(video)[0].fps is None


def selected(count: int, sel: FrameSelection) -> list[int]:
    """The reference: the indices ``sel`` keeps of ``count`` frames."""
    kept = [i for i in range(count) if i >= sel.start and (sel.end is None or i < sel.end) and (i - sel.start) % sel.every == 0]
    return kept[:sel.max_frames]


SELECTIONS = [dict(), dict(every=3), dict(start=5), dict(end=10), dict(max_frames=4), dict(start=29),
              dict(every=4, start=2, end=20, max_frames=3), dict(every=7, start=3, end=100), dict(every=50)]


@pytest.mark.parametrize("kind", ["video", "folder"])
@pytest.mark.parametrize("fields", SELECTIONS, ids=lambda f: ",".join(f"{k}={v}" for k, v in f.items()) or "all")
def test_selection(tmp_path, kind, fields):
    source = index_video(tmp_path / "clip.mp4") if kind == "video" else index_folder(tmp_path / "frames")
    sel = FrameSelection(**fields)
    info, frames = open_frames(source, sel)
    assert info.frames == 30
    got = list(frames)
    assert [i for i, _, _ in got] == selected(30, sel)
    assert [index_of(frame) for _, _, frame in got] == selected(30, sel)
    if kind == "folder":
        assert [name for _, name, _ in got] == [f"f{i}" for i in selected(30, sel)]


@pytest.mark.parametrize("kind", ["video", "folder"])
def test_long_side(tmp_path, kind):
    source = index_video(tmp_path / "clip.mp4") if kind == "video" else index_folder(tmp_path / "frames", 2)
    shapes = {None: (H, W), 540: (H, W), W: (H, W), 40: (30, 40), 32: (24, 32), 5: (4, 5)}
    for long_side, shape in shapes.items():
        info, frames = open_frames(source, FrameSelection(long_side=long_side, max_frames=1))
        assert (info.width, info.height) == (W, H)  # native size
        _, _, frame = next(frames)
        assert frame.shape == (*shape, 3) and frame.dtype == np.uint8
        if long_side == 32:  # INTER_AREA keeps flat colours
            assert np.abs(frame[2:10, 2:14].astype(int) - (255, 0, 0)).max() <= 12
            assert np.abs(frame[2:10, 18:30].astype(int) - (0, 0, 255)).max() <= 12


def test_downscale_averages(tmp_path):
    """INTER_AREA: one-pixel stripes downscaled by 2 become their mean, not one of them."""
    folder = tmp_path / "frames"
    folder.mkdir()
    stripes = np.zeros((H, W, 3), np.uint8)
    stripes[:, ::2] = 255
    write_image(folder / "stripes.png", stripes)
    frame = next(open_frames(folder, FrameSelection(long_side=W // 2))[1])[2]
    assert frame.shape == (H // 2, W // 2, 3) and np.abs(frame.astype(int) - 128).max() <= 1


@pytest.mark.parametrize("field, value, message", [
    ("every", 0, "every: must be an integer >= 1, got 0"),
    ("every", 1.5, "every: must be an integer >= 1, got 1.5"),
    ("every", True, "every: must be an integer >= 1, got True"),
    ("every", "2", "every: must be an integer >= 1, got '2'"),
    ("start", -1, "start: must be an integer >= 0, got -1"),
    ("end", 0, "end: must be an integer > `start` (0), got 0"),
    ("max_frames", 0, "max_frames: must be an integer >= 1, got 0"),
    ("max_frames", 2.0, "max_frames: must be an integer >= 1, got 2.0"),
    ("long_side", -1, "long_side: must be an integer >= 0, got -1"),
])
def test_bad_selection_is_named(field, value, message):
    with pytest.raises(ValueError) as err:
        FrameSelection(**{field: value})
    assert str(err.value) == message
    with pytest.raises(ValueError, match=r"^end: must be an integer > `start` \(5\), got 3$"):
        FrameSelection(start=5, end=3)
    assert FrameSelection(every=np.int64(2)).every == 2


def test_start_beyond_the_end(tmp_path, capture):
    video, folder = index_video(tmp_path / "clip.mp4"), index_folder(tmp_path / "frames", 3)
    with pytest.raises(ValueError, match=rf"^{tmp_path}/frames: `start` 3 is beyond the end: the folder has 3 images$"):
        open_frames(folder, FrameSelection(start=3))
    with pytest.raises(ValueError, match=rf"^{video}: `start` 30 is beyond the end: the video declares 30 frames$"):
        open_frames(video, FrameSelection(start=30))
    capture({cv2.CAP_PROP_FRAME_COUNT: 0})  # a container that declares no frame count: found at the end
    info, frames = open_frames(video, FrameSelection(start=40))
    assert info.frames is None
    with pytest.raises(ValueError, match=rf"^{video}: `start` 40 is beyond the end: the video has 30 frames$"):
        next(frames)


# --------------------------------------------------------------------------------------------------
# laziness


def test_one_frame_decoded_at_a_time(tmp_path, capture):
    video = index_video(tmp_path / "long.mp4", 300)
    made = capture()
    info, frames = open_frames(video)
    assert info.frames == 300 and made[0].calls == {"grab": 1}  # frame 0 checked, nothing converted
    started = time.perf_counter()
    index, _, frame = next(frames)
    assert time.perf_counter() - started < 0.5
    assert index == 0 and made[0].calls == {"grab": 1, "retrieve": 1}
    assert next(frames)[0] == 1 and made[0].calls == {"grab": 2, "retrieve": 2}

    made = capture()
    got = [i for i, _, _ in open_frames(video, FrameSelection(every=50, end=260))[1]]
    assert got == [0, 50, 100, 150, 200, 250]
    assert made[-1].calls == {"grab": 260, "retrieve": 6}  # skipped frames grabbed only; none past `end`
    made = capture()
    assert len(list(open_frames(video, FrameSelection(start=10, max_frames=2))[1])) == 2
    assert made[-1].calls == {"grab": 12, "retrieve": 2}  # stops at max_frames


def test_folder_reads_one_image_at_a_time(tmp_path, monkeypatch):
    folder = index_folder(tmp_path / "frames", 10)
    read = []
    real = video_input.cv2.imdecode
    monkeypatch.setattr(cv2, "imdecode", lambda *a: read.append(1) or real(*a))
    info, frames = open_frames(folder, FrameSelection(every=3))
    assert len(read) == 1  # the first image: the folder's size
    assert next(frames)[0] == 0 and len(read) == 1
    assert next(frames)[0] == 3 and len(read) == 2
    info, frames = open_frames(folder, FrameSelection(start=9))
    assert [i for i, _, _ in frames] == [9] and len(read) == 4  # images 1-8 never opened


# --------------------------------------------------------------------------------------------------
# rotation


def portrait_scene() -> np.ndarray:
    """uint8 RGB [64, 32, 3], upright: red on top, green at the bottom, a blue block top-left."""
    img = np.zeros((64, 32, 3), np.uint8)
    img[:32] = (255, 0, 0)
    img[32:] = (0, 255, 0)
    img[:16, :16] = (0, 0, 255)
    return img


# What the camera stores for a scene shown rotated clockwise by the key: the scene rotated back.
STORED = {90: cv2.ROTATE_90_COUNTERCLOCKWISE, 180: cv2.ROTATE_180, 270: cv2.ROTATE_90_CLOCKWISE}


@pytest.mark.parametrize("degrees", [90, 180, 270])
@pytest.mark.parametrize("opencv_rotates", [True, False], ids=["opencv-rotates", "build-without-auto-rotation"])
def test_rotation_metadata_applied_once(tmp_path, capture, degrees, opencv_rotates):
    scene = portrait_scene()
    video = write_video(tmp_path / "phone.mp4", [cv2.rotate(scene, STORED[degrees])] * 3)
    set_rotation(video, degrees)
    capture(no_auto=not opencv_rotates)
    info, frames = open_frames(video, FrameSelection(long_side=None))
    assert (info.width, info.height, info.rotation) == (32, 64, degrees)
    frames = list(frames)
    assert len(frames) == 3
    for _, _, frame in frames:
        assert frame.shape == (64, 32, 3)
        assert np.abs(frame[4:12, 4:12].astype(int) - (0, 0, 255)).max() <= 16  # upright: blue block top-left
        assert np.abs(frame[4:28, 20:28].astype(int) - (255, 0, 0)).max() <= 16
        assert np.abs(frame[36:60, 4:28].astype(int) - (0, 255, 0)).max() <= 16
    _, frames = open_frames(video, FrameSelection(long_side=16))
    assert next(frames)[2].shape == (16, 8, 3)


def test_opencv_build_rotates_by_itself(tmp_path):
    """What this module relies on in the OpenCV it ships with: FFmpeg reads the metadata, auto-rotation is on."""
    video = write_video(tmp_path / "phone.mp4", [cv2.rotate(portrait_scene(), STORED[90])])
    set_rotation(video, 90)
    cap = REAL_CAPTURE(str(video), cv2.CAP_FFMPEG)
    assert cap.get(cv2.CAP_PROP_ORIENTATION_META) == 90 and cap.get(cv2.CAP_PROP_ORIENTATION_AUTO) == 1
    assert (cap.get(cv2.CAP_PROP_FRAME_WIDTH), cap.get(cv2.CAP_PROP_FRAME_HEIGHT)) == (32, 64)
    assert cap.read()[1].shape == (64, 32, 3)


def test_a_frame_of_another_size_is_refused(tmp_path, capture):
    """A frame the decoder returns at another size than the video declares (rotated twice, say) is an error."""
    video = index_video(tmp_path / "clip.mp4", 3)
    capture({cv2.CAP_PROP_FRAME_WIDTH: H, cv2.CAP_PROP_FRAME_HEIGHT: W})
    _, frames = open_frames(video)
    with pytest.raises(ValueError, match=rf"^{video}: frame 0 is {W}x{H}, the video declares {H}x{W}$"):
        next(frames)


# --------------------------------------------------------------------------------------------------
# folders


def test_folder_natural_order_names_and_ignored_files(tmp_path):
    folder = tmp_path / "frames"
    folder.mkdir()
    for i, name in enumerate(["frame10.png", "frame2.png", "Frame1.JPG", "frame3.webp", "frame4.bmp", "frame05.jpeg"]):
        write_image(folder / name, frame_rgb(i))
    write_image(folder / ".frame0.png", frame_rgb(0))  # hidden: ignored
    (folder / "notes.txt").write_text("not an image")
    (folder / "frame6.png.bak").write_bytes(b"")
    (folder / "frame7.png").mkdir()  # a folder named like an image
    info, frames = open_frames(folder, FrameSelection(long_side=None))
    assert info == VideoInfo(folder, "folder", None, 6, W, H, 0)
    got = list(frames)
    assert [(i, name) for i, name, _ in got] == [(0, "Frame1"), (1, "frame2"), (2, "frame3"), (3, "frame4"),
                                               (4, "frame05"), (5, "frame10")]
    assert [index_of(frame) for _, _, frame in got] == [2, 1, 3, 4, 5, 0]
    assert np.array_equal(got[1][2], frame_rgb(1))  # PNG: exact, RGB


def test_folder_names_are_safe_file_stems(tmp_path):
    folder = tmp_path / "frames"
    folder.mkdir()
    for name in ["my frame (1).png", "-2.png", "été.png", "a.b.png"]:
        write_image(folder / name, frame_rgb(0))
    names = [name for _, name, _ in open_frames(folder)[1]]
    assert names == ["_2", "a.b", "my_frame__1_", "_t_"]
    write_image(folder / "a.b.jpg", frame_rgb(0))
    with pytest.raises(ValueError, match=r"a\.b\.png: its frame name 'a\.b' is also the name of a\.b\.jpg"):
        open_frames(folder)


def test_folder_of_mixed_sizes(tmp_path):
    folder = tmp_path / "frames"
    folder.mkdir()
    write_image(folder / "1.png", frame_rgb(0))
    write_image(folder / "2.png", frame_rgb(1))
    write_image(folder / "3.png", frame_rgb(2, w=W, h=H + 2))
    _, frames = open_frames(folder)
    assert [next(frames)[0], next(frames)[0]] == [0, 1]  # the frames before it come first
    with pytest.raises(ValueError, match=rf"^{folder}/3\.png: image is 64x50, the first image 1\.png is 64x48; every "):
        next(frames)


@pytest.mark.parametrize("content", [b"", b"not an image at all", "half-png", "half-jpg"])
def test_corrupt_image_is_named(tmp_path, content):
    folder = tmp_path / "frames"
    folder.mkdir()
    write_image(folder / "1.png", frame_rgb(0))
    bad = folder / ("2.jpg" if content == "half-jpg" else "2.png")
    if isinstance(content, str):
        ok, data = cv2.imencode(bad.suffix, frame_rgb(1))
        content = data.tobytes()[: data.size // 2]
    bad.write_bytes(content)
    _, frames = open_frames(folder)
    assert next(frames)[0] == 0
    with pytest.raises(ValueError, match=rf"^{bad}: not a readable image \(corrupt or unsupported, {len(content)} bytes\)$"):
        next(frames)
    bad.rename(folder / "0.png")  # the first image: refused when the folder is opened
    with pytest.raises(ValueError, match=r"0\.png: not a readable image"):
        open_frames(folder)


@pytest.mark.parametrize("size", [(1, 40), (40, 1)])
def test_one_pixel_wide_image(tmp_path, size):
    folder = tmp_path / "frames"
    folder.mkdir()
    write_image(folder / "thin.png", np.zeros((size[1], size[0], 3), np.uint8))
    with pytest.raises(ValueError, match=rf"thin\.png: the image is {size[0]}x{size[1]}; a frame side must be 2 to 16384"):
        open_frames(folder)


@pytest.mark.parametrize("suffix", [".png", ".jpg", ".bmp"])
def test_huge_image_refused_from_its_header(tmp_path, suffix):
    folder = tmp_path / "frames"
    folder.mkdir()
    ok, data = cv2.imencode(suffix, np.zeros((2, MAX_SIDE + 1, 3), np.uint8))
    (folder / f"wide{suffix}").write_bytes(data.tobytes()[: data.size // 2])  # cut: refused from its header alone
    with pytest.raises(ValueError, match=rf"wide\{suffix}: the image is 16385x2; a frame side must be 2 to 16384"):
        open_frames(folder)


def test_exif_orientation_applied(tmp_path):
    """A JPEG stored landscape with EXIF orientation 6 (rotate 90 clockwise to show) comes out portrait."""
    stored = np.zeros((32, 64, 3), np.uint8)
    stored[:, :16] = (255, 0, 0)  # red on the left: on top once shown
    ok, data = cv2.imencode(".jpg", cv2.cvtColor(stored, cv2.COLOR_RGB2BGR))
    tiff = b"MM\x00\x2a" + struct.pack(">IH", 8, 1) + struct.pack(">HHIHH", 0x0112, 3, 1, 6, 0) + struct.pack(">I", 0)
    app1 = b"\xff\xe1" + struct.pack(">H", 8 + len(tiff)) + b"Exif\x00\x00" + tiff
    folder = tmp_path / "frames"
    folder.mkdir()
    (folder / "photo.jpg").write_bytes(data.tobytes()[:2] + app1 + data.tobytes()[2:])
    info, frames = open_frames(folder, FrameSelection(long_side=None))
    assert (info.width, info.height, info.rotation) == (32, 64, 0)
    frame = next(frames)[2]
    assert frame.shape == (64, 32, 3)
    assert frame[:12, :, 0].mean() > 200 and frame[24:, :, 0].mean() < 40


# --------------------------------------------------------------------------------------------------
# bad sources


def test_missing_and_empty_sources(tmp_path):
    with pytest.raises(FileNotFoundError, match=rf"^{tmp_path}/nothing.mp4: no such video file or image folder$"):
        open_frames(tmp_path / "nothing.mp4")
    folder = tmp_path / "frames"
    folder.mkdir()
    with pytest.raises(ValueError, match=rf"^{folder}: no images in the folder \(files ending in \.png, \.jpg"):
        open_frames(folder)
    (folder / "notes.txt").write_text("x")
    with pytest.raises(ValueError, match=rf"^{folder}: no images in the folder"):
        open_frames(str(folder))
    image = write_image(folder / "one.png", frame_rgb(0))
    with pytest.raises(ValueError, match=rf"^{image}: is an image, not a video; give the folder of the frames$"):
        open_frames(image)


def test_unreadable_videos(tmp_path):
    junk = tmp_path / "junk.mp4"
    junk.write_bytes(b"\x00" * 1000)
    with pytest.raises(ValueError, match=rf"^{junk}: OpenCV cannot open it as a video"):
        open_frames(junk)
    # OpenCV's MP4: the index (moov) comes last, so a cut file has none
    video = index_video(tmp_path / "clip.mp4")
    cut = tmp_path / "cut.mp4"
    cut.write_bytes(video.read_bytes()[: video.stat().st_size // 2])
    with pytest.raises(ValueError, match=rf"^{cut}: OpenCV cannot open it as a video"):
        open_frames(cut)
    # an AVI cut right after its header: declares 30 frames, holds none
    avi = index_video(tmp_path / "clip.avi", fourcc="MJPG")
    data = avi.read_bytes()
    empty = tmp_path / "empty.avi"
    empty.write_bytes(data[: data.find(b"movi") + 4])
    with pytest.raises(ValueError, match=rf"^{empty}: no frame could be decoded$"):
        open_frames(empty)


def test_truncated_video_yields_what_it_has(tmp_path):
    avi = index_video(tmp_path / "clip.avi", fourcc="MJPG")  # AVI: the header first, frames in order
    cut = tmp_path / "cut.avi"
    cut.write_bytes(avi.read_bytes()[: avi.stat().st_size // 2])
    info, frames = open_frames(cut)
    assert info.frames == 30
    got = []
    with pytest.raises(ValueError) as err:
        for index, _, frame in frames:
            got.append(index)
            assert index_of(frame) == index
    assert 5 < len(got) < 25 and got == list(range(len(got)))
    assert str(err.value) == (f"{cut}: decoding stopped after frame {got[-1]} ({len(got)} of the 30 frames the video "
                              f"declares): a truncated or damaged video")
    assert [i for i, _, _ in open_frames(cut, FrameSelection(end=len(got)))[1]] == got  # no error before the cut


def test_estimated_frame_count_is_not_truncation(tmp_path, capture):
    """An mkv's count is duration x fps; with a variable rate it exceeds the frames held, their time does not."""
    video = index_video(tmp_path / "clip.mp4")  # 30 frames at 25 fps: the last at 1.16 s
    capture({cv2.CAP_PROP_FRAME_COUNT: 34, cv2.CAP_PROP_FPS: 28.5})  # the last frame's time: 34 frames at 28.5
    assert [i for i, _, _ in open_frames(video)[1]] == list(range(30))
    capture({cv2.CAP_PROP_FRAME_COUNT: 34})  # 34 frames at 25 fps: 1.36 s, 4 frames missing
    with pytest.raises(ValueError, match=rf"^{video}: decoding stopped after frame 29 \(30 of the 34 frames"):
        list(open_frames(video)[1])


def test_frame_side_limit_checked_before_decoding(tmp_path, capture, monkeypatch):
    video = index_video(tmp_path / "clip.mp4", 3)
    monkeypatch.setattr(video_input, "MAX_SIDE", 60)
    made = capture()
    with pytest.raises(ValueError, match=rf"^{video}: the video's frame size is 64x48; a frame side must be 2 to 60 pixels$"):
        open_frames(video)
    assert made[0].calls == {}


def test_8k_frame_downscaled_without_a_full_size_copy(tmp_path):
    big = np.zeros((4320, 7680, 3), np.uint8)
    big[:, :3840] = (255, 0, 0)
    video = write_video(tmp_path / "8k.mp4", [big], fps=30)
    folder = tmp_path / "frames"
    folder.mkdir()
    write_image(folder / "8k.jpg", big)
    del big
    for source in (video, folder):
        tracemalloc.start()
        try:
            info, frames = open_frames(source)
            _, _, frame = next(frames)
            peak = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
        assert (info.width, info.height) == (7680, 4320)
        assert frame.shape == (304, 540, 3)
        assert np.abs(frame[:, 10:260].astype(int) - (255, 0, 0)).max() <= 12
        assert frame[:, 280:].max() <= 12
        assert peak < 1.3 * 7680 * 4320 * 3  # the decoded frame once, nothing else at full size


def test_no_torch():
    result = run_python("import trioman.runtime.video_input", block_torch=True)
    assert result.returncode == 0, result.stderr
