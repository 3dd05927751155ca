"""What ``trioman import exavatar`` and ``trioman import smplx-fits`` read and how (toolkit/importers/), each setting
with its option (runtime/options.py): the library's defaults and the command's are these fields. Standard-library
imports only: the command builds its parsers from these fields."""

from __future__ import annotations

from dataclasses import dataclass

from trioman.runtime.options import check_options, integer, option

DATASETS = ("xhumans", "neuman", "custom")
GENDERS = ("neutral", "male", "female")
# X-Humans' fits: "auto" (ExAvatar's when every take holds them, else X-Humans' own), "exavatar" (the takes that
# hold ExAvatar's fitting output; the others are left out), "xhumans" (X-Humans' own fits and body).
XHUMANS_FITS = ("auto", "exavatar", "xhumans")
UP_SOURCES = ("body", "cameras", "none")  # where the world's up comes from (``common.upright``)


@dataclass(frozen=True)
class ImportOptions:
    """What both sources share."""

    flat_hand_mean: bool = option(False, help="hand poses are absolute (off: relative to SMPL-X's hand mean, as smplx "
                                              "and ExAvatar use)")
    up: str = option("body", choices=UP_SOURCES,
                     help="where the world's up comes from: the body's spine over the frames, the cameras' mean up, or "
                          "none (the capture's +y); the world is turned so the person stands along +z")

    def __post_init__(self) -> None:
        check_options(self)


@dataclass(frozen=True, kw_only=True)
class ExAvatarOptions(ImportOptions):
    dataset: str = option(choices=DATASETS, help="the capture's layout")
    fits: str = option("auto", choices=XHUMANS_FITS,
                       help="X-Humans: the fits to pose the body with: ExAvatar's fitting output of each take "
                            "(TAKE/smplx_optimized/smplx_params/, with its identity; 'exavatar' leaves out takes without "
                            "it), X-Humans' own SMPLX/*.pkl on X-Humans' own body (gender.txt, mean_shape_smplx.npy), or "
                            "auto: ExAvatar's when every take holds them, else X-Humans' own")
    allow_pickle: bool = option(False, help="read pickled files (X-Humans' SMPLX/*.pkl fits); unpickling runs code, use "
                                            "only on files you trust")
    gender: str | None = option(None, choices=GENDERS, help="SMPL-X model",
                                default_text="the fits' own: male, ExAvatar's; X-Humans' own fits: its gender.txt")
    num_betas: int | None = option(None, check=integer(1), help="shape coefficients",
                                   default_text="the fits' own: 100, ExAvatar's; X-Humans' own fits: its mean shape's 10")


@dataclass(frozen=True, kw_only=True)
class SmplxFitsOptions(ImportOptions):
    gender: str = option("neutral", choices=GENDERS, help="SMPL-X model")
    test_every: int = option(5, check=integer(0), help="every K-th frame is a test frame (0: none)")
