"""An avatar driven by a motion, as an MP4 (``trioman animate``: trioman/commands/animate.py).

Runs on the runtime alone (numpy + onnxruntime + OpenCV, no torch): numpy FK + LBS poses the
Gaussians (plus the avatar's ONNX pose-dependent deltas), the numpy splat renderer draws them.
The camera is ``fixed`` (one view that keeps the whole clip in frame) or ``orbit`` (a full turn about
the subject over the clip). Reports the time per frame by stage. The options of ``trioman animate``
(``AnimateOptions``) and ``trioman render`` (``RenderOptions``) are declared here, and their checks
(``parse_background``, ``check_size``, ``check_video_size``, ``check_angles``) name the parameter; the commands
show their flags. Standard-library imports only at module level.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from trioman.runtime.options import check_options, option

def parse_background(background: str):
    """'r,g,b' in [0, 1] -> float32 [3]."""
    import numpy as np

    try:
        bg = np.array([float(v) for v in background.split(",")], dtype=np.float32)
    except ValueError:
        raise ValueError(f"background: expected r,g,b numbers in [0, 1], got {background!r}") from None
    if bg.shape != (3,) or not np.all((bg >= 0) & (bg <= 1)):
        raise ValueError(f"background: expected three numbers in [0, 1], got {background!r}")
    return bg


EMPTY_ALPHA = 1.0 / 255  # a frame whose every pixel has less coverage shows nothing of the avatar


def check_size(size: int) -> int:
    if not 16 <= size <= 4096:
        raise ValueError(f"size: must lie in [16, 4096] pixels, got {size}")
    return size


def check_video_size(size: int) -> int:
    """An MP4's side: even (the codec would drop an odd last row and column), else refused."""
    if check_size(size) % 2:
        raise ValueError(f"size: {size} is odd, and an MP4 needs even sides (it would be {size - 1}x{size - 1}); "
                         f"use {size - 1} or {size + 1}")
    return size


def check_angles(**degrees: float) -> None:
    for name, value in degrees.items():
        if not math.isfinite(value):
            raise ValueError(f"{name}: must be a finite number of degrees, got {value}")


def _frames(value: Any) -> str | None:
    from trioman.runtime.formats.motion import MAX_FRAMES

    return None if isinstance(value, int) and not isinstance(value, bool) and 1 <= value <= MAX_FRAMES \
        else f"must lie in [1, {MAX_FRAMES}] (an hour at 30 fps)"


def _fps(value: Any) -> str | None:
    from trioman.runtime.formats.motion import FPS_RANGE

    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and FPS_RANGE[0] <= value <= FPS_RANGE[1]
    return None if ok else f"must lie in [{FPS_RANGE[0]}, {FPS_RANGE[1]}] frames per second"


@dataclass(frozen=True)
class ImageOptions:
    """How an animated or rendered avatar looks."""

    background: str = option("1,1,1", metavar="R,G,B", help="background colour, r,g,b in [0, 1]")
    pose_dependent: bool = option(True, help="the avatar's pose-dependent deltas")

    def __post_init__(self) -> None:
        check_options(self)
        parse_background(self.background)


@dataclass(frozen=True)
class AnimateOptions(ImageOptions):
    """``trioman animate``'s settings (``animate`` defaults to them)."""

    camera: str = option("fixed", choices=("fixed", "orbit"), help="camera path")
    azimuth: float = option(20.0, help="degrees; 0 = in front of the subject")
    elevation: float = option(5.0, help="degrees above the subject's centre")
    size: int = option(512, help="image side in pixels, even")
    frames: int | None = option(None, check=_frames, default_text="its own", help="length of a shipped motion")
    fps: float | None = option(None, check=_fps, default_text="the motion's", help="video frame rate")

    def __post_init__(self) -> None:
        super().__post_init__()
        check_video_size(self.size)
        check_angles(azimuth=self.azimuth, elevation=self.elevation)


@dataclass(frozen=True)
class RenderOptions(ImageOptions):
    """``trioman render``'s settings."""

    camera: str = option("front", metavar="CAMERA", help="front | AZ,EL (degrees about the posed body; 0,0 = in "
                                                         "front) | subject (the camera of --pose SUBJECT@FRAME)")
    size: int | None = option(None, default_text="512; subject camera: its size", help="image side in pixels")

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.size is not None:
            check_size(self.size)


def clip_points(avatar, motion, samples: int = 12):
    """Posed Gaussian centres at up to ``samples`` frames spread over the clip (for framing). -> [M, 3]."""
    import numpy as np

    idx = np.unique(np.linspace(0, motion.num_frames - 1, min(samples, motion.num_frames)).round().astype(int))
    return np.concatenate([avatar.gaussians(motion.pose[i], motion.trans[i], pose_dependent=False).means for i in idx])


def animate(avatar, motion, out, camera: str = AnimateOptions.camera, azimuth: float = AnimateOptions.azimuth,
            elevation: float = AnimateOptions.elevation, size: int = AnimateOptions.size,
            background=AnimateOptions.background, fps: float | None = AnimateOptions.fps, frames_dir=None,
            pose_dependent: bool = AnimateOptions.pose_dependent, progress: bool = True) -> dict:
    """Render ``motion`` (a Motion in the avatar's joint order) with ``avatar`` (runtime Avatar) to an MP4
    at ``out``; angles in degrees, ``background`` "r,g,b" or three numbers in [0, 1]. The camera frames the bulk of the clip (``frame_points``); a clip whose
    every frame shows nothing of the avatar is a ValueError and writes nothing, and a failure leaves no video
    and none of this call's ``frames_dir`` PNGs. -> timings: frames, seconds, ms per frame for posing and
    rendering, and the frames that show nothing (``empty``)."""
    import time
    from pathlib import Path

    import numpy as np
    from tqdm import tqdm

    from trioman.runtime.cameras import frame_points, orbit_viewmat
    from trioman.runtime.image_io import VideoWriter, write_png
    from trioman.runtime.render import rasterize

    if camera not in ("fixed", "orbit"):
        raise ValueError(f"camera: expected 'fixed' or 'orbit', got {camera!r}")
    size = check_video_size(size)
    check_angles(azimuth=azimuth, elevation=elevation)
    bg = parse_background(background) if isinstance(background, str) else np.asarray(background, dtype=np.float32)
    out = Path(out)
    if not out.parent.is_dir():
        raise FileNotFoundError(f"out: the folder {out.parent} does not exist")
    if frames_dir is not None:
        frames_dir = Path(frames_dir)
        frames_dir.mkdir(parents=True, exist_ok=True)
    az0, el = np.deg2rad(azimuth), np.deg2rad(elevation)
    try:
        K, viewmat, center = frame_points(clip_points(avatar, motion), (size, size), az0, el)
    except ValueError as err:
        raise ValueError(f"motion {motion.name}: the avatar cannot be framed: {err}") from None
    distance = float(np.linalg.norm(np.linalg.inv(viewmat)[:3, 3] - center))
    t_pose = t_render = 0.0
    empty: list[int] = []
    written: list[Path] = []
    start = time.perf_counter()
    try:
        with VideoWriter(out, fps or motion.fps, (size, size)) as video:
            for i in tqdm(range(motion.num_frames), desc="animate", unit="frame", disable=None if progress else True):
                if camera == "orbit":
                    viewmat = orbit_viewmat(center, az0 + 2 * np.pi * i / motion.num_frames, el, distance)
                t0 = time.perf_counter()
                g = avatar.gaussians(motion.pose[i], motion.trans[i], pose_dependent=pose_dependent)
                t1 = time.perf_counter()
                r = rasterize(*g, viewmat, K, size, size, background=bg)
                t_render += time.perf_counter() - t1
                t_pose += t1 - t0
                if not r.alpha.max() >= EMPTY_ALPHA:
                    empty.append(i)
                video.write(r.rgb)
                if frames_dir is not None:
                    written.append(frames_dir / f"{i:05d}.png")
                    write_png(written[-1], r.rgb)
            if len(empty) == motion.num_frames:
                raise ValueError(f"motion {motion.name}: all {len(empty)} frames show nothing of the avatar (out of "
                                 f"view of the camera); no video written")
    except BaseException:
        for path in written:
            path.unlink(missing_ok=True)
        raise
    n = motion.num_frames
    total = time.perf_counter() - start
    return {"frames": n, "seconds": total, "pose_ms": 1000 * t_pose / n, "render_ms": 1000 * t_render / n,
            "ms_per_frame": 1000 * total / n, "size": size, "gaussians": avatar.num_gaussians, "video": str(out),
            "empty": empty}
