"""What ``trioman triplets`` builds (toolkit/corpus/triplets.py), each setting with its option (runtime/options.py): the
library's defaults and the command's are these fields. Standard-library imports only: the command builds its
parser from these fields."""

from __future__ import annotations

from dataclasses import dataclass

from trioman.runtime.options import check_options, integer, option


@dataclass(frozen=True)
class TripletsOptions:
    draws: int | None = option(None, metavar="N", check=integer(1),
                               help="synthetic subjects: N Generator draws per training frame, the truth at each as GT "
                                    "(what a Refiner meets during augmentation) instead of the subject's frames")
    seed: int = option(0, check=integer(0), help="the draws' seed")

    def __post_init__(self) -> None:
        check_options(self)
