"""The frames of a video file or of a folder of images, one at a time: what ``trioman fit`` reads.

``open_frames(source, selection)`` -> ``(VideoInfo, iterator of (index, name, frame))``, each frame uint8 RGB
[H, W, 3], downscaled to ``selection.long_side``. The iterator decodes one frame at a time; skipped frames
of a video are only grabbed (``VideoCapture.grab``: demuxed and decoded, never converted or copied).

Videos are read through OpenCV's FFmpeg backend, in decode order. A phone's rotation metadata
(``CAP_PROP_ORIENTATION_META``: the clockwise angle that shows the video upright) is applied once: by OpenCV
when its backend takes ``CAP_PROP_ORIENTATION_AUTO`` (FFmpeg's does, and has it on by default), by this
module only when it does not. Every decoded frame must have the size the video declares, so a frame
rotated by 90 degrees twice (or not at all) is an error, not a sideways subject.

A video that stops short of the frame count its container declares (a truncated or damaged file) yields
the frames read so far, then the iterator raises a ValueError naming the file and the last good frame.
Short means by more than ``max(2, 5%)`` of the declared count both in frames read and in time (the last
frame's timestamp x fps): containers without a frame index (mkv, webm) declare an estimate, duration x
fps, which a variable frame rate makes larger than the frames they hold. An MP4 cut before its index (the
``moov`` box, at the end of OpenCV's and most phones' files) cannot be opened at all.

Images are decoded with ``cv2.IMREAD_COLOR``: the EXIF orientation of a JPEG is applied by the decoder
(``VideoInfo.rotation`` stays 0), alpha is dropped, gray becomes RGB, 16-bit becomes 8-bit.
"""

from __future__ import annotations

import math
import re
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import cv2
import numpy as np

from trioman.runtime.formats.subject import check_frame_name
from trioman.runtime.frame_selection import FrameSelection
from trioman.runtime.image_io import quiet_opencv

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".webp")
MAX_SIDE = 16384  # a frame side above this is refused
MIN_SIDE = 2  # a frame side below this is refused

_ROTATE = {90: cv2.ROTATE_90_CLOCKWISE, 180: cv2.ROTATE_180, 270: cv2.ROTATE_90_COUNTERCLOCKWISE}
_JPEG_SOF = {0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF}
_UNSAFE_NAME = re.compile(r"^[.\-]|[^A-Za-z0-9_.\-]")  # what check_frame_name refuses, one character at a time

Frame = tuple[int, str, np.ndarray]  # (index in the source, name, uint8 RGB [H, W, 3])


@dataclass(frozen=True)
class VideoInfo:
    """What the source declares. ``width`` x ``height``: the native size after rotation, before any resize."""

    path: Path
    kind: str  # "video" or "folder"
    fps: float | None  # the container's frame rate; None for a folder, or when unknown, 0 or not finite
    frames: int | None  # frames the container declares (None when unknown); a folder: its image count
    width: int
    height: int
    rotation: int  # degrees (clockwise) applied to honour the video's rotation metadata: 0, 90, 180 or 270


def open_frames(source: str | Path, selection: FrameSelection | None = None) -> tuple[VideoInfo, Iterator[Frame]]:
    """-> (info, iterator of (index in the source, name, frame uint8 RGB [H, W, 3] resized per ``selection``)).

    ``source``: a video file (any container OpenCV's FFmpeg backend reads; names ``f"{index:06d}"``) or a
    folder of images (the files ending in ``IMAGE_SUFFIXES``, any case, in natural order, hidden files and
    other files ignored; index: the position in that order; name: the file's stem with every character a
    frame name may not hold replaced by ``_``). The source is opened and its first frame checked here; an
    error later (a damaged frame, an image of another size) is raised by the iterator once the frames
    before it are yielded. Errors are ValueErrors (FileNotFoundError for a missing source) starting with
    the path.
    """
    selection = selection if selection is not None else FrameSelection()
    path = Path(source)
    if path.is_dir():
        return _open_folder(path, selection)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such video file or image folder")
    if path.suffix.lower() in IMAGE_SUFFIXES:
        raise ValueError(f"{path}: is an image, not a video; give the folder of the frames")
    return _open_video(path, selection)


def _check_sides(path: Path, width: int, height: int, what: str) -> None:
    if not (MIN_SIDE <= width <= MAX_SIDE and MIN_SIDE <= height <= MAX_SIDE):
        raise ValueError(f"{path}: {what} is {width}x{height}; a frame side must be {MIN_SIDE} to {MAX_SIDE} pixels")


def scaled_size(width: int, height: int, long_side: int | None) -> tuple[int, int]:
    """The (W, H) a ``width`` x ``height`` frame is read at when its long side is limited to ``long_side``
    (FrameSelection's rule: only downscaled, aspect kept, sides rounded, at least 1; 0 or None: native)."""
    if not long_side or max(width, height) <= long_side:
        return width, height
    scale = long_side / max(width, height)
    return max(1, round(width * scale)), max(1, round(height * scale))


def _fit(bgr: np.ndarray, long_side: int | None, rotation: int = 0) -> np.ndarray:
    """BGR uint8 [h, w, 3] as decoded -> RGB uint8 [H, W, 3]: downscaled to ``long_side``, then rotated by
    ``rotation`` degrees clockwise (the small image, not the decoded one, is converted and rotated)."""
    h, w = bgr.shape[:2]
    size = scaled_size(w, h, long_side)
    if size != (w, h):
        bgr = cv2.resize(bgr, size, interpolation=cv2.INTER_AREA)
    if rotation:
        bgr = cv2.rotate(bgr, _ROTATE[rotation])
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


# --------------------------------------------------------------------------------------------------
# videos


def _declared(value: float) -> float | None:
    return value if math.isfinite(value) and value > 0 else None


def _open_video(path: Path, selection: FrameSelection) -> tuple[VideoInfo, Iterator[Frame]]:
    with quiet_opencv():
        cap = cv2.VideoCapture(str(path), cv2.CAP_FFMPEG)
    if not cap.isOpened():
        raise ValueError(f"{path}: OpenCV cannot open it as a video (not a video, an unsupported codec, or a "
                         f"damaged file)")
    try:
        meta = cap.get(cv2.CAP_PROP_ORIENTATION_META)
        meta = round(meta) % 360 if math.isfinite(meta) else 0
        meta = meta if meta in _ROTATE else 0  # OpenCV applies right angles only
        opencv_rotates = cap.set(cv2.CAP_PROP_ORIENTATION_AUTO, 1) and cap.get(cv2.CAP_PROP_ORIENTATION_AUTO) != 0
        own_rotation = 0 if opencv_rotates else meta
        # The decoder's frame size: rotated already when OpenCV rotates.
        decoded = (int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)))
        width, height = decoded[::-1] if own_rotation in (90, 270) else decoded
        fps = _declared(cap.get(cv2.CAP_PROP_FPS))
        frames = _declared(cap.get(cv2.CAP_PROP_FRAME_COUNT))
        info = VideoInfo(path, "video", fps, None if frames is None else int(frames), width, height, meta)
        _check_sides(path, width, height, "the video's frame size")
        if info.frames is not None and selection.start >= info.frames:
            raise ValueError(f"{path}: `start` {selection.start} is beyond the end: the video declares "
                             f"{info.frames} frames")
        if not _grab(cap):
            raise ValueError(f"{path}: no frame could be decoded")
    except BaseException:
        cap.release()
        raise
    return info, _video_frames(cap, info, decoded, own_rotation, selection)


def _grab(cap: cv2.VideoCapture) -> bool:
    """The next frame grabbed (OpenCV's log silenced), or False at the end of the stream or on an error."""
    with quiet_opencv():
        return cap.grab()


def _video_frames(cap: cv2.VideoCapture, info: VideoInfo, decoded: tuple[int, int], rotation: int,
                  selection: FrameSelection) -> Iterator[Frame]:
    """The kept frames of ``cap``, whose frame 0 is grabbed; ``rotation``: what to rotate (clockwise degrees)."""
    path, kept, index = info.path, 0, 0
    try:
        while True:
            if selection.keeps(index):
                with quiet_opencv():
                    ok, bgr = cap.retrieve()
                if not ok:
                    raise ValueError(f"{path}: frame {index} could not be decoded (the last good frame is "
                                     f"{index - 1}): a damaged video")
                if (bgr.shape[1], bgr.shape[0]) != decoded:
                    raise ValueError(f"{path}: frame {index} is {bgr.shape[1]}x{bgr.shape[0]}, the video declares "
                                     f"{decoded[0]}x{decoded[1]}")
                yield index, f"{index:06d}", _fit(bgr, selection.long_side, rotation)
                kept += 1
                if kept == selection.max_frames:
                    return
            index += 1
            if selection.end is not None and index >= selection.end:
                return
            last_ms = cap.get(cv2.CAP_PROP_POS_MSEC)  # frame index - 1's time, which a failed grab resets
            if not _grab(cap):
                break
    finally:
        cap.release()
    # The stream ended after `index` frames; the frames its last frame's time accounts for count too (VFR).
    elapsed = max(index, last_ms * info.fps / 1000 + 1 if info.fps else 0)
    if info.frames is not None and info.frames - elapsed > max(2, info.frames // 20):
        raise ValueError(f"{path}: decoding stopped after frame {index - 1} ({index} of the {info.frames} frames the "
                         f"video declares): a truncated or damaged video")
    if kept == 0:
        raise ValueError(f"{path}: `start` {selection.start} is beyond the end: the video has {index} frames")


# --------------------------------------------------------------------------------------------------
# folders of images


def _natural_key(name: str) -> tuple:
    """Sort key: digit runs compare as numbers (frame2 before frame10), letters without case, ties by name."""
    parts = re.split(r"(\d+)", name.casefold())
    return tuple(int(p) if i % 2 else p for i, p in enumerate(parts)), name


def _header_size(data: memoryview) -> tuple[int, int] | None:
    """(width, height) that a PNG, JPEG or BMP declares in its header, before decoding; None for other
    formats or a header this does not find. (A WebP side cannot exceed 16383.)"""
    if data[:8] == b"\x89PNG\r\n\x1a\n" and data[12:16] == b"IHDR" and len(data) >= 24:
        return struct.unpack(">II", data[16:24])
    if data[:2] == b"BM" and len(data) >= 26:
        width, height = struct.unpack("<ii", data[18:26])
        return abs(width), abs(height)
    if data[:2] == b"\xff\xd8":
        pos = 2
        while pos + 9 <= len(data) and data[pos] == 0xFF:
            marker = data[pos + 1]
            if marker == 0xFF:  # a fill byte
                pos += 1
            elif marker in _JPEG_SOF:
                height, width = struct.unpack(">HH", data[pos + 5:pos + 9])
                return width, height
            elif marker == 0xDA:  # start of scan: no size before the pixels
                return None
            else:
                pos += 2 + struct.unpack(">H", data[pos + 2:pos + 4])[0]
    return None


def _read_image(path: Path) -> np.ndarray:
    """An image file -> BGR uint8 [H, W, 3] (EXIF orientation applied); its size checked before decoding."""
    try:
        data = np.fromfile(path, dtype=np.uint8)  # works for non-ASCII paths, unlike cv2.imread
    except OSError as err:
        raise ValueError(f"{path}: cannot be read ({err.strerror})") from None
    size = _header_size(memoryview(data))
    if size is not None and max(size) > MAX_SIDE:
        _check_sides(path, *size, "the image")
    with quiet_opencv():
        bgr = cv2.imdecode(data, cv2.IMREAD_COLOR) if data.size else None
    if bgr is None:
        raise ValueError(f"{path}: not a readable image (corrupt or unsupported, {data.size} bytes)")
    _check_sides(path, bgr.shape[1], bgr.shape[0], "the image")
    return bgr


def _open_folder(path: Path, selection: FrameSelection) -> tuple[VideoInfo, Iterator[Frame]]:
    files = sorted((p for p in path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and not p.name.startswith(".")
                    and p.is_file()), key=lambda p: _natural_key(p.name))
    if not files:
        raise ValueError(f"{path}: no images in the folder (files ending in {', '.join(IMAGE_SUFFIXES)})")
    names: dict[str, Path] = {}
    for file in files:
        name = check_frame_name(_UNSAFE_NAME.sub("_", file.stem), file, "frame name")
        if name in names:
            raise ValueError(f"{file}: its frame name {name!r} is also the name of {names[name].name}; rename one")
        names[name] = file
    indices = range(selection.start, len(files) if selection.end is None else min(selection.end, len(files)),
                    selection.every)[:selection.max_frames]
    if not indices:
        raise ValueError(f"{path}: `start` {selection.start} is beyond the end: the folder has {len(files)} images")
    first = _read_image(files[0])
    info = VideoInfo(path, "folder", None, len(files), first.shape[1], first.shape[0], 0)
    return info, _folder_frames(files, list(names), indices, first if indices[0] == 0 else None, info, selection)


def _folder_frames(files: list[Path], names: list[str], indices: range, first: np.ndarray | None,
                   info: VideoInfo, selection: FrameSelection) -> Iterator[Frame]:
    """The images ``indices`` of ``files``; ``first``: image 0 already decoded, or None."""
    for index in indices:
        bgr = first if index == 0 else _read_image(files[index])
        first = None
        if (bgr.shape[1], bgr.shape[0]) != (info.width, info.height):
            raise ValueError(f"{files[index]}: image is {bgr.shape[1]}x{bgr.shape[0]}, the first image {files[0].name} "
                             f"is {info.width}x{info.height}; every frame must have the same size")
        yield index, names[index], _fit(bgr, selection.long_side)
