"""Image and video I/O.

In numpy an image is float32 in [0, 1]: RGB [H, W, 3] or gray [H, W], HWC. On disk it is an 8-bit
PNG (OpenCV stores BGR; the conversion happens here and nowhere else). Files are written atomically
(runtime/outputs.py).
"""

from __future__ import annotations

import contextlib
import struct
import zlib
from pathlib import Path
from typing import Iterable, Iterator

import cv2
import numpy as np

from trioman.runtime.outputs import PathLike, atomic_path, atomic_write_bytes, not_a_file

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
# PNG colour type -> channels once decoded by OpenCV without alpha (palette decodes to colour).
_PNG_CHANNELS = {0: 1, 2: 3, 3: 3, 4: 2, 6: 4}

# --------------------------------------------------------------------------------------------------
# images


def to_uint8(img: np.ndarray, name: str = "image") -> np.ndarray:
    """float image in [0, 1] -> uint8 (clipped, rounded); uint8 passes, bool -> 0/255.

    NaN/Inf or another dtype is a ValueError naming ``name``.
    """
    img = np.asarray(img)
    if img.dtype == np.uint8:
        return img
    if img.dtype == np.bool_:
        return img.astype(np.uint8) * 255
    if not np.issubdtype(img.dtype, np.floating):
        raise ValueError(f"{name}: expected a float image in [0, 1] (or uint8), got dtype {img.dtype}")
    img = img.astype(np.float32, copy=False)
    bad = ~np.isfinite(img)
    if bad.any():
        raise ValueError(f"{name}: {int(bad.sum())} non-finite value(s) (NaN/Inf)")
    return np.rint(np.clip(img, 0.0, 1.0) * 255.0).astype(np.uint8)


def _check_image_shape(img: np.ndarray, name: str) -> None:
    if not (img.ndim == 2 or (img.ndim == 3 and img.shape[2] == 3)) or img.shape[0] == 0 or img.shape[1] == 0:
        raise ValueError(f"{name}: expected shape [H, W, 3] (RGB) or [H, W] (gray), got {list(img.shape)}")


def encode_png(img: np.ndarray, name: str = "image") -> bytes:
    """float32 RGB [H, W, 3] or gray [H, W] in [0, 1] (or uint8) -> PNG bytes."""
    img = np.asarray(img)
    _check_image_shape(img, name)
    u8 = to_uint8(img, name)
    if u8.ndim == 3:
        u8 = cv2.cvtColor(np.ascontiguousarray(u8), cv2.COLOR_RGB2BGR)
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(u8))
    if not ok:
        raise ValueError(f"{name}: OpenCV could not encode a PNG of shape {list(img.shape)}")
    return buf.tobytes()


def write_png(path: PathLike, img: np.ndarray) -> None:
    """Write a float32 RGB [H, W, 3] or gray [H, W] image in [0, 1] as an 8-bit PNG, atomically."""
    atomic_write_bytes(path, encode_png(img, name=str(path)))


@contextlib.contextmanager
def quiet_opencv() -> Iterator[None]:
    """OpenCV's own log (``[ WARN ]`` and libpng's messages) silenced inside the block.

    A decoder that fails says so through its return value and the caller's one-line error; OpenCV's
    warnings would otherwise reach the terminal first. Errors (cv2.error) still raise.
    """
    logging = getattr(getattr(cv2, "utils", None), "logging", None)
    if logging is None or not hasattr(logging, "setLogLevel"):
        yield
        return
    level = logging.getLogLevel()
    logging.setLogLevel(logging.LOG_LEVEL_ERROR if level > logging.LOG_LEVEL_ERROR else level)
    try:
        yield
    finally:
        logging.setLogLevel(level)


def _png_damage(data: np.ndarray) -> str | None:
    """Why a PNG's bytes are damaged (a chunk past the end, a critical chunk's CRC wrong, no IEND), or
    None (whole, or not a PNG).

    Only the chunk framing is checked (zlib's CRC-32 of the critical chunks, which libpng refuses too; it
    skips an ancillary chunk with a bad CRC); the pixels are left to the decoder. Checked here so that
    the error is one line: libpng prints its own complaint to stderr.
    """
    raw = data.tobytes() if data.size >= 8 else b""
    if raw[:8] != _PNG_SIGNATURE:
        return None
    pos, size = 8, len(raw)
    while pos + 8 <= size:
        length, kind = struct.unpack(">I4s", raw[pos:pos + 8])
        end = pos + 12 + length
        name = kind.decode("latin-1")
        if end > size:
            return f"truncated PNG: chunk {name!r} at byte {pos} needs {end} bytes, the file has {size}"
        (crc,) = struct.unpack(">I", raw[end - 4:end])
        if not kind[0] & 0x20 and zlib.crc32(raw[pos + 4:end - 4]) != crc:  # critical chunks, as libpng
            return f"corrupt PNG: chunk {name!r} at byte {pos} fails its CRC"
        if kind == b"IEND":
            return None
        pos = end
    return f"truncated PNG: no IEND chunk in its {size} bytes"


def read_png(path: PathLike, mode: str | None = None) -> np.ndarray:
    """Read an image file -> float32 in [0, 1]: RGB [H, W, 3] or gray [H, W].

    ``mode``: None keeps the file's kind (gray stays [H, W], colour becomes RGB, alpha is dropped);
    "rgb" or "gray" converts to that kind. 16-bit files are scaled by 1/65535.
    """
    if mode not in (None, "rgb", "gray"):
        raise ValueError(f"mode: expected None, 'rgb' or 'gray', got {mode!r}")
    path = Path(path)
    problem = not_a_file(path)
    if problem == "missing file":
        raise FileNotFoundError(f"{path}: image file not found")
    if problem is not None:
        raise ValueError(f"{path}: {problem}")
    data = np.fromfile(path, dtype=np.uint8)  # works for non-ASCII paths, unlike cv2.imread
    damage = _png_damage(data)
    if damage:
        raise ValueError(f"{path}: not a readable image ({damage})")
    with quiet_opencv():
        img = cv2.imdecode(data, cv2.IMREAD_UNCHANGED) if data.size else None
    if img is None:
        raise ValueError(f"{path}: not a readable image (corrupt or unsupported, {data.size} bytes)")
    if img.dtype == np.uint8:
        img = img.astype(np.float32) / 255.0
    elif img.dtype == np.uint16:
        img = img.astype(np.float32) / 65535.0
    else:
        img = img.astype(np.float32)
    if img.ndim == 3:
        ch = img.shape[2]
        if ch == 1:
            img = img[..., 0]
        elif ch == 2:  # gray + alpha
            img = img[..., 0]
        else:  # BGR or BGRA
            img = np.ascontiguousarray(img[..., 2::-1])
    if mode == "rgb" and img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=2)
    elif mode == "gray" and img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
    return img


def png_header(path: PathLike) -> tuple[int, int, int]:
    """(width, height, channels) of a PNG from its first 33 bytes, without decoding the pixels.

    channels: 1 gray, 2 gray + alpha, 3 RGB or palette, 4 RGBA. Raises FileNotFoundError for a missing
    file and ValueError naming the path for a file that is not a PNG.
    """
    path = Path(path)
    try:
        with open(path, "rb") as f:
            head = f.read(33)
    except (FileNotFoundError, IsADirectoryError, NotADirectoryError):
        raise FileNotFoundError(f"{path}: image file not found") from None
    if len(head) < 33 or head[:8] != _PNG_SIGNATURE or head[12:16] != b"IHDR":
        raise ValueError(f"{path}: not a PNG file (bad signature or header, {len(head)} bytes read)")
    width, height, _depth, color_type = struct.unpack(">IIBB", head[16:26])
    if width == 0 or height == 0 or color_type not in _PNG_CHANNELS:
        raise ValueError(f"{path}: corrupt PNG header (width {width}, height {height}, colour type {color_type})")
    return int(width), int(height), _PNG_CHANNELS[color_type]


# --------------------------------------------------------------------------------------------------
# video


class VideoWriter:
    """Write float32 RGB [H, W, 3] frames (or [H, W] gray) in [0, 1] to an MP4, atomically.

    The video goes to a temporary ``.mp4`` next to ``path`` and is renamed onto ``path`` by
    ``close()``; leaving the ``with`` block with an exception (or calling ``abort()``) removes it.
    The frame size comes from ``size=(width, height)`` or the first frame; every frame must match. MP4
    codecs need even sides (mp4v silently drops an odd last row or column): an odd side is padded by
    repeating its last row or column, and ``video_size`` is the size written.

        with VideoWriter("out.mp4", fps=30) as video:
            for frame in frames:
                video.write(frame)
    """

    def __init__(self, path: PathLike, fps: float, size: tuple[int, int] | None = None, fourcc: str = "mp4v"):
        self.path = Path(path)
        fps = float(fps)
        if not np.isfinite(fps) or fps <= 0:
            raise ValueError(f"fps: expected a positive number, got {fps}")
        if len(fourcc) != 4:
            raise ValueError(f"fourcc: expected 4 characters, got {fourcc!r}")
        if not self.path.parent.is_dir():
            raise FileNotFoundError(f"{self.path}: the folder {self.path.parent} does not exist")
        self.fps = fps
        self.fourcc = fourcc
        self.size = None if size is None else (int(size[0]), int(size[1]))
        self.count = 0
        self._writer: cv2.VideoWriter | None = None
        self._ctx = atomic_path(self.path, suffix=self.path.suffix or ".mp4")
        self._tmp = self._ctx.__enter__()
        self._done = False

    @property
    def video_size(self) -> tuple[int, int] | None:
        """(width, height) of the video file: ``size`` rounded up to even sides."""
        return None if self.size is None else (self.size[0] + self.size[0] % 2, self.size[1] + self.size[1] % 2)

    def _open(self) -> None:
        writer = cv2.VideoWriter(str(self._tmp), cv2.VideoWriter_fourcc(*self.fourcc), self.fps, self.video_size)
        if not writer.isOpened():
            self.abort()
            raise ValueError(
                f"{self.path}: OpenCV could not open a video writer (fourcc {self.fourcc!r}, "
                f"size {self.size[0]}x{self.size[1]}, fps {self.fps}); this OpenCV build may lack the codec"
            )
        self._writer = writer

    def write(self, frame: np.ndarray) -> None:
        if self._done:
            raise ValueError(f"{self.path}: the video writer is closed")
        frame = np.asarray(frame)
        name = f"{self.path}: frame {self.count}"
        _check_image_shape(frame, name)
        h, w = frame.shape[:2]
        if self.size is None:
            self.size = (w, h)
        if (w, h) != self.size:
            raise ValueError(f"{name}: expected size {self.size[0]}x{self.size[1]} (W x H), got {w}x{h}")
        if self._writer is None:
            self._open()
        u8 = to_uint8(frame, name)
        bgr = cv2.cvtColor(u8, cv2.COLOR_GRAY2BGR) if u8.ndim == 2 else cv2.cvtColor(np.ascontiguousarray(u8), cv2.COLOR_RGB2BGR)
        if self.video_size != self.size:
            bgr = np.pad(bgr, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge")
        self._writer.write(bgr)
        self.count += 1

    def close(self) -> None:
        """Finish the file and rename it into place. A video needs at least one frame."""
        if self._done:
            return
        if self.count == 0:
            self.abort()
            raise ValueError(f"{self.path}: no frames were written")
        self._writer.release()
        self._writer = None
        self._done = True
        self._ctx.__exit__(None, None, None)

    def abort(self) -> None:
        """Discard the video: nothing is left at ``path`` or in the temporary file."""
        if self._done:
            return
        self._done = True
        if self._writer is not None:
            self._writer.release()
            self._writer = None
        err = RuntimeError("video aborted")
        with contextlib.suppress(RuntimeError):
            self._ctx.__exit__(RuntimeError, err, None)

    def __enter__(self) -> "VideoWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()

    def __del__(self) -> None:  # a writer dropped without close() leaves no temporary file
        with contextlib.suppress(Exception):
            self.abort()


def write_video(path: PathLike, frames: Iterable[np.ndarray], fps: float, fourcc: str = "mp4v") -> int:
    """Write float32 RGB [H, W, 3] frames in [0, 1] to an MP4 atomically; returns the frame count."""
    with VideoWriter(path, fps, fourcc=fourcc) as video:
        for frame in frames:
            video.write(frame)
    return video.count
