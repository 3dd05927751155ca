"""What ``trioman synth-corpus`` builds (toolkit/corpus/build.py), each setting with its option (runtime/options.py).
Standard-library imports only: the command builds its parser from these fields."""

from __future__ import annotations

from dataclasses import dataclass

from trioman.runtime.options import check_options, integer, option
from trioman.toolkit.synth.config import STYLES


@dataclass(frozen=True)
class CorpusConfig:
    train_subjects: int = option(10, flag="--subjects", check=integer(1), help="training subjects")
    heldout_subjects: int = option(2, flag="--heldout", check=integer(1), help="held-out subjects")
    size: int = option(128, check=integer(16), help="image side")
    frames: int = option(96, check=integer(6), help="frames per subject")
    seed: int = option(1000, check=integer(0), help="first subject seed (subject i has seed + i)")
    iterations: int = option(600, check=integer(1), help="baseline training iterations (quick preset otherwise)")
    baseline_frames: str = option("all", choices=("all", "subset"),
                                  help="what training subjects' baselines see: all frames (paper) or every 4th "
                                       "(held-out subjects: their train split)")
    subset_stride: int = 4
    style: str = option("plain", choices=STYLES, help="the subjects' synth style (trioman synth --style)")

    def __post_init__(self) -> None:
        check_options(self)
        if self.subset_stride < 1:
            raise ValueError(f"subset_stride: must be >= 1, got {self.subset_stride}")

    @property
    def names(self) -> list[tuple[str, str]]:
        """(name, role) per subject, role "train" or "heldout"."""
        n = self.train_subjects + self.heldout_subjects
        return [(f"s{i:02d}", "train" if i < self.train_subjects else "heldout") for i in range(n)]
