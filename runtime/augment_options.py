"""What ``trioman augment`` makes (runtime/augment/, ``augment()``), each setting with its option (runtime/options.py):
the library's defaults and the command's are these fields; ``augment()`` checks the values (its errors name them).
Standard-library imports only: the command builds its parser from these fields."""

from __future__ import annotations

from dataclasses import dataclass

from trioman.runtime.options import check_options, option
from trioman.runtime.pseudo_kinds import MASKS


@dataclass(frozen=True)
class AugmentOptions:
    per_frame: int = option(2, help="Generator candidates per source frame")
    threshold: float | None = option(None, help="drop the chosen candidate when its Examiner score is below this, in [0, 1]")
    seed: int = option(0, help="run seed; each frame's seed derives from it")
    frames: str = option("train", choices=("train", "all"), help="source frames: the train split or all frames")
    limit: int | None = option(None, help="use only the first N source frames (quick runs)")
    mask: str = option("carried", choices=MASKS,
                       help="the pseudo frames' mask: the body mesh plus the source frame's mask carried to the draw "
                            "(carried) or the avatar render's own alpha (alpha, the paper's)")
    keep_carried: bool | None = option(None, default_text="on with --refiner",
                                       help="with --refiner: keep the real pixels carried to the draw and take the "
                                            "Refiner's output only where nothing was carried (measured best, "
                                            "docs/augmentation.md)")
    texture: int = option(0, metavar="TEXELS",
                          help="take the aligned reference's colour from a texture of this side fused from every source "
                               "frame wherever its texels were seen (runtime/texture_fusion.py; 0: carried pixels only)")
    threads: int | None = option(None, default_text="onnxruntime's own", help="onnxruntime intra-op threads")

    def __post_init__(self) -> None:
        check_options(self)
