"""What ``trioman synth`` renders (toolkit/synth/subject.py), each setting with its option (trioman/options.py).

Standard-library imports only: the command builds its parser from these fields.
"""

from __future__ import annotations

from dataclasses import dataclass

from trioman.runtime.options import check_options, integer, number, option

# Novel views for the test motions: (azimuth deg, elevation deg, distance m, body yaw rad).
TEST_VIEWS = {
    "arms_raised": (30.0, 25.0, 3.3, 0.5),
    "squat": (-60.0, -10.0, 2.9, -2.2),
    "step": (100.0, 18.0, 3.2, 2.7),
    "wave": (-25.0, 35.0, 3.4, -0.7),
}
STYLES = ("plain", "realistic")
CAPTURES = ("turn", "steps")


def parse_aspect(text: str) -> float:
    """'9:16' or '0.5625' -> width / height."""
    w, sep, h = text.partition(":")
    try:
        return float(w) / float(h) if sep else float(text)
    except (ValueError, ZeroDivisionError):
        raise ValueError(f"expected W:H (e.g. 9:16) or a number, got {text!r}") from None


@dataclass(frozen=True)
class SynthConfig:
    seed: int = option(0, check=integer(), help="body shape, clothing and noise seed")
    size: int = option(256, check=integer(16), help="image side in pixels, the long side with --aspect")
    frames: int = option(120, check=integer(2 + len(TEST_VIEWS)),
                         help="total frames, training turn + test motions (one per test motion at least)")
    test_fraction: float = option(0.2, check=number(0, 1, lo_open=True, hi_open=True),
                                  help="fraction of frames in the test split")
    pose_noise_deg: float = option(0.0, flag="--pose-noise", metavar="DEG", check=number(0, 90),
                                   help="std in degrees of the noise added to the stored poses, mimicking fitted "
                                        "parameters")
    fill: float = 0.75  # fraction of the image height the rest body spans from the training camera
    texture_size: int = 1024
    supersample: int = 2
    body_model: str = "anny"
    coverage: float = option(1.0, metavar="FRACTION", check=number(0, 1, lo_open=True),
                             help="fraction of a full turn the training frames span, from facing the camera: 1 all "
                                  "round, 0.5 half a turn, 0.2 front only (a capture seen from one side)")
    style: str = option("plain", choices=STYLES,
                        help="plain: painted clothes on a bald body on black; realistic: hair, garments and shoes of "
                             "their own geometry, a room, a key light with soft shadows, a hand-held phone's jitter, "
                             "exposure drift, motion blur, noise and JPEG")
    capture: str = option("turn", choices=CAPTURES,
                          help="the training motion: turn in place, or a few steps towards the camera, then the turn")
    aspect: float = option(1.0, metavar="W:H", check=number(0.25, 4), default_text="1:1", parse=parse_aspect,
                           help="image aspect (width / height, W:H or a number), e.g. 9:16 for a portrait phone video")
    handheld_deg: float = option(0.3, flag="--handheld", metavar="DEG", check=number(0, 5),
                                 help="realistic style: std of the phone's rotation jitter in degrees, 0 for a tripod")
    outfit: str = option("", metavar="TOP,BOTTOM,HAIR,OUTER", default_text="drawn from the seed",
                         help="realistic style: e.g. tshirt,skirt,long,none")

    def __post_init__(self) -> None:
        check_options(self)
        if min(self.width, self.height) < 16:
            raise ValueError(f"aspect: the short side would be {min(self.width, self.height)} pixels (< 16) at size {self.size}")
        if self.style == "plain" and self.outfit:
            raise ValueError(f"outfit: only the realistic style wears an outfit, got {self.outfit!r} with style 'plain'")
        if self.outfit:
            from trioman.toolkit.synth.garments import BOTTOMS, HAIRSTYLES, OUTERWEAR, TOPS

            parts = self.outfit.split(",")
            if len(parts) != 4:
                raise ValueError(f"outfit: expected 'top,bottom,hair,outer' (tops {'/'.join(TOPS)}; bottoms {'/'.join(BOTTOMS)}; "
                                 f"hair {'/'.join(HAIRSTYLES)}; outer {'/'.join(OUTERWEAR)}), got {self.outfit!r}")
            try:
                self.scene_outfit()
            except ValueError as exc:
                raise ValueError(f"outfit: {exc}") from None
        if not 0.1 <= self.fill <= 0.95:
            raise ValueError(f"fill: must lie in [0.1, 0.95], got {self.fill}")
        if self.supersample < 1 or self.texture_size < 64:
            raise ValueError(f"supersample/texture_size: got {self.supersample}/{self.texture_size}")

    @property
    def num_test(self) -> int:
        return max(len(TEST_VIEWS), int(round(self.frames * self.test_fraction)))

    @property
    def width(self) -> int:
        return self.size if self.aspect >= 1 else 2 * int(round(self.size * self.aspect / 2))

    @property
    def height(self) -> int:
        return self.size if self.aspect <= 1 else 2 * int(round(self.size / self.aspect / 2))

    def scene_outfit(self):
        """The outfit asked for (toolkit/synth/garments.py's Outfit), or None (drawn from the seed)."""
        from trioman.toolkit.synth.garments import Outfit

        return Outfit(*self.outfit.split(",")) if self.outfit else None
