"""What ``trioman fit`` fits (toolkit/fit/fitter.py's ``fit_sequence``, toolkit/fit/run.py's ``fit_video``), each
setting a command exposes with its option (runtime/options.py). Standard-library imports only: the command builds its
parser from these fields."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from trioman.runtime.frame_selection import FrameSelection
from trioman.runtime.options import check_options, integer, number, option

if TYPE_CHECKING:
    from trioman.runtime.person import TrackerConfig


@dataclass(frozen=True)
class FitConfig:
    """Settings of ``fit_sequence``; weights are relative to the keypoint term."""

    focal: float | None = None  # pixels; None: the phone prior times the long side
    refine_focal: bool = True
    phenotype: tuple[float, ...] | None = None  # Anny's shape when known (PHENOTYPE_LABELS order): not fitted
    # each keyframe is fitted from a body at rest turned to the world landmarks' yaw; the other frames start from
    # their nearest keyframe's pose and stay near it, so dense keyframes leave fewer frames in a neighbour's minimum
    # (docs/fit.md, "Measured": 24 -> 144 keyframes)
    keyframes: int = option(144, check=integer(1), help="frames fitted first, each from a body at rest, with the shape "
                                                        "and camera; every other frame starts from its nearest keyframe")
    key_iterations: int = option(300, check=integer(1), help="the keyframes' iterations")
    all_iterations: int = option(250, flag="--iterations", check=integer(1), help="the iterations over every frame")
    lr: float = 0.03
    w_silhouette: float = 0.5
    w_world: float = 0.5
    # the world term's weight on the bones that end at a shoulder (the shoulder line, the torso's sides), which place
    # the arms' roots; None: ``w_world`` (the arms themselves are not in the term, ``keypoints.LIMBS``)
    w_world_shoulders: float | None = None
    w_smooth: float = 20.0
    w_pose: float = 0.002
    w_limits: float = 1.0
    w_upright: float = 0.2
    w_shape: float = 0.05
    w_height: float = 1.0  # the height phenotype: a monocular view cannot tell a tall person far away from a short one near
    w_focal: float = 0.1
    silhouette_points: int = 500
    repairs: int = 2  # passes that restart badly fitted keyframes from a neighbour
    seed: int = 0

    def __post_init__(self) -> None:
        if self.focal is not None and not (math.isfinite(self.focal) and self.focal > 0):
            raise ValueError(f"focal: must be a positive number of pixels, got {self.focal!r}")
        check_options(self)
        for name in ("silhouette_points",):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ValueError(f"{name}: must be an integer >= 1, got {value!r}")
        if self.w_world_shoulders is not None and not (math.isfinite(self.w_world_shoulders) and self.w_world_shoulders >= 0):
            raise ValueError(f"w_world_shoulders: must be a finite number >= 0 (or None: w_world), got {self.w_world_shoulders!r}")



TRACK_SIDE = 540  # the long side the person model and the fit see by default (docs/fit.md, 'Measured')


def _tracker_config() -> "TrackerConfig":
    from trioman.runtime.person import TrackerConfig

    return TrackerConfig()


@dataclass(frozen=True)
class FitRunConfig:
    """What ``fit_video`` reads and how it fits."""

    selection: FrameSelection = field(default_factory=FrameSelection)
    track_side: int | None = option(None, check=integer(0), metavar="PX", default_text=f"{TRACK_SIDE}, or --long-side when larger",
                                    help="the person model and the fit see the frames at this long side (0: native); the "
                                         "subject is written at --long-side, its camera and masks scaled")
    focal: float | None = option(None, metavar="PX", check=number(0, lo_open=True),
                                 default_text="a phone's, refined by the fit",
                                 help="the focal length in pixels at the output size (or --fov)")
    fov_deg: float | None = option(None, flag="--fov", metavar="DEG", check=number(1, 170),
                                   help="the long side's field of view in degrees (or --focal)")
    cuts: tuple[int, ...] = option((), sep=",", check=integer(1), metavar="FRAMES", default_text="none: one shot",
                                   help="the source's frame numbers where a new shot begins (a video edited from several "
                                        "clips, comma-separated): each shot is fitted as its own motion")
    test_every: int = option(8, check=lambda v: None if isinstance(v, int) and not isinstance(v, bool) and (v == 0 or v >= 2)
                             else "must be 0 (no test frames) or an integer >= 2",
                             help="every N-th kept frame goes to the test split (0: none)")
    fit: FitConfig = field(default_factory=FitConfig)
    tracker: TrackerConfig = field(default_factory=_tracker_config)

    @property
    def tracking(self) -> FrameSelection:
        """The selection the person model and the fit read: ``selection`` at ``track_side``."""
        side, out = self.track_side, self.selection.long_side
        if side is None:
            side = 0 if not out else max(out, TRACK_SIDE)
        return dataclasses.replace(self.selection, long_side=side)

    def __post_init__(self) -> None:
        if self.focal is not None and self.fov_deg is not None:
            raise ValueError("focal and fov_deg: give one of them, not both")
        check_options(self)
