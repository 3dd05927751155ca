"""Which frames of a video or a folder are read, and their size (runtime/video_input.py), each setting with its
option (runtime/options.py). Standard-library imports only: ``trioman fit`` builds its parser from these fields."""

from __future__ import annotations

from dataclasses import dataclass

from trioman.runtime.options import check_options, integer, option


@dataclass(frozen=True)
class FrameSelection:
    """Which frames of the source are kept, and their size.

    Frame ``i`` is kept when ``start <= i < end`` and ``(i - start) % every == 0``, at most ``max_frames``
    of them. A frame whose long side exceeds ``long_side`` is downscaled to it (``cv2.INTER_AREA``, aspect
    kept, sides rounded, at least 1); smaller frames are kept as they are; 0 or None keeps the native size.
    """

    every: int = option(1, check=integer(1), help="keep every N-th frame")
    start: int = option(0, check=integer(0), help="first frame")
    end: int | None = option(None, default_text="the end", help="stop before this frame")
    max_frames: int | None = option(None, check=integer(1), default_text="all", help="at most this many frames")
    long_side: int | None = option(540, check=integer(0), metavar="PX",
                                   help="frames larger than this (pixels, the long side) are scaled down to it (0: native)")

    def __post_init__(self) -> None:
        check_options(self)
        if self.end is not None and integer(self.start + 1)(self.end) is not None:
            raise ValueError(f"end: must be an integer > `start` ({self.start}), got {self.end!r}")

    def keeps(self, index: int) -> bool:
        """Whether frame ``index`` is kept, ``max_frames`` aside."""
        return self.start <= index and (self.end is None or index < self.end) and (index - self.start) % self.every == 0
