"""What ``trioman view`` serves and how (``ViewerConfig``), and its timing mode (``TimingOptions``), each setting with
its option (runtime/options.py): the library's defaults and the command's are these fields. Standard-library
imports only: the command builds its parser from these fields."""

from __future__ import annotations

from dataclasses import dataclass

from trioman.runtime.options import check_options, integer, number, option


@dataclass(frozen=True)
class ViewerConfig:
    host: str = option("127.0.0.1", metavar="HOST", help="address to listen on (127.0.0.1: this machine only; "
                                                         "0.0.0.0 serves the avatar to the whole network)")
    port: int = option(8080, metavar="PORT", help="port (0: any free port)")
    fps: float | None = option(None, check=number(0, lo_open=True), default_text="the motion's", help="playback rate")
    azimuth: float = 20.0  # initial camera, degrees (0 = in front of the subject)
    elevation: float = 5.0  # degrees above the subject's centre

    def __post_init__(self) -> None:
        check_options(self)


@dataclass(frozen=True)
class TimingOptions:
    updates: int | None = option(None, flag="--time", metavar="N", check=integer(1),
                                 help="time N pose updates over the motion's frames, print the median cost and exit")

    def __post_init__(self) -> None:
        check_options(self)
