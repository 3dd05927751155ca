"""The config of ``trioman bench ablation`` (bench/ablation/): the rows it trains, the avatar runs' plan and the
benchmark's own settings, each field with its option (runtime/options.py). The augmented runs' schedule is an
AugmentConfig (``train --augment``'s defaults; ``SCHEDULE`` its options the command takes), not a copy of its knobs.
Standard-library imports only (the command builds its parser from these fields)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from trioman.bench.common import check_names, check_path
from trioman.bench.config import OUT
from trioman.runtime.options import check_options, integer, number, option
from trioman.toolkit.corpus_training_options import REFINER_SIZE_NAMES
from trioman.toolkit.synth.config import STYLES
from trioman.toolkit.train.augment_config import AugmentConfig

# (name, augment mode, refiner condition, seeded): the order of the report's rows.
VARIANTS = (
    ("baseline", None, None, True),
    ("baseline_long", None, None, True),
    ("G", "coarse", None, False),
    ("aligned", "aligned", None, False),
    ("GR_none", "refined", "none", False),
    ("GR_tex", "refined", "tex", False),
    ("GR_tex+geo", "refined", "tex+geo", False),
    ("GR_warp+geo", "refined", "warp+geo", False),
    ("GRk_warp+geo", "refined", "warp+geo", False),
    ("GRE", "examined", "warp+geo", True),
    ("ceiling_seen", "truth_seen", None, False),
    ("ceiling", "truth", None, False),
)
# Levers: variants beyond the paper's, trained when their option is given; same tuple layout.
LEVERS = (("GRd_tex+geo", "refined", "tex+geo", False),)
ALL_VARIANTS = VARIANTS + LEVERS
SCHEDULE = ("start", "refresh", "pool", "mask")  # AugmentConfig's options that bench ablation takes (the same flags)


@dataclass(frozen=True)
class AblationPlan:
    iterations: int = option(600, check=integer(1), help="real-frame steps of every avatar run")
    seeds: int = option(2, check=integer(1), help="seeds of the baseline, the control and the full system")
    # the augmented runs' schedule and mask (each row sets its own mode and models): `train --augment`'s by default
    schedule: AugmentConfig = field(default_factory=AugmentConfig)
    detail_sigma: float | None = option(None, metavar="PX", check=number(0),
                                        help="also train the lever GRd_tex+geo, refined pseudo-GT keeping only the "
                                             "Refiner's detail (its change minus that change blurred by PX pixels)")
    coverage: float = option(1.0, metavar="FRACTION", check=number(0, 1, lo_open=True),
                             help="re-render the held-out subjects with their training turn spanning this share of a "
                                  "full turn (1: the corpus's subjects)")
    pose_noise: float = option(0.0, metavar="DEG", check=number(0, 90),
                               help="re-render the held-out subjects with this fitting noise on their stored poses "
                                    "(evaluated at the true test poses)")
    reach: float = option(1.0, metavar="FACTOR", help="the Generator's camera sigmas (azimuth, elevation, "
                                                      "log-distance) as a multiple of their defaults")
    poses: str = option("true", choices=("true", "fit"),
                        help="the held-out subjects' poses: true (with --pose-noise) or fit (each re-rendered as a "
                             "video, every frame, and fitted by `trioman fit`; evaluated at the fitted test poses)")
    video_side: int = option(540, metavar="PX", check=integer(0),
                             help="with --poses fit: the long side of the held-out subjects' videos, tracked and fitted "
                                  "at that size as a phone's video is (`trioman fit --track-side`), the subject written at "
                                  "the corpus's size (0: the video at the subject's own size)")

    def __post_init__(self) -> None:
        check_options(self)
        if self.poses == "fit" and self.pose_noise:
            raise ValueError(f"pose_noise: the fitted poses carry the fit's own error; with poses 'fit' it must be 0, "
                             f"got {self.pose_noise!r}")
        if not (isinstance(self.reach, (int, float)) and 0 < self.reach <= 10):
            raise ValueError(f"reach: the Generator's camera sigmas as a multiple of their defaults, in (0, 10], got {self.reach!r}")

    @property
    def capture(self) -> str:
        """The suffix of the subjects (and the unaugmented runs) of this plan's capture regime ('' for the corpus's own)."""
        if self.poses == "fit":
            return f"-cov{self.coverage:g}-fit" + (f"{self.video_side}" if self.video_side else "")
        return "" if (self.coverage, self.pose_noise) == (1.0, 0.0) else f"-cov{self.coverage:g}-noise{self.pose_noise:g}"

    @property
    def regime(self) -> str:
        """The suffix of the augmented runs: the capture regime, and the Generator's reach when not the default."""
        return self.capture + ("" if self.reach == 1.0 else f"-reach{self.reach:g}")

    @property
    def camera(self) -> tuple[float, float, float] | None:
        """AugmentConfig.camera of the plan's reach (None: the Generator's defaults)."""
        from trioman.runtime.generator import GeneratorConfig

        g = GeneratorConfig()
        return None if self.reach == 1.0 else tuple(self.reach * s for s in (g.azimuth_sigma, g.elevation_sigma, g.distance_sigma))

    def run(self, out: Path, heldout: str, variant: str, seed: int = 0) -> Path:
        """The run folder of ``variant`` on held-out subject ``heldout``: an unaugmented run does not depend on the
        Generator's reach, so regimes that differ only in reach share it."""
        augmented = next(m for n, m, *_ in ALL_VARIANTS if n == variant) is not None
        return out / "runs" / (heldout + (self.regime if augmented else self.capture)) / f"{variant.replace('+', '_')}_s{seed}"

    @property
    def variants(self) -> tuple[tuple, ...]:
        """The (name, mode, condition, seeded) rows this plan trains."""
        return VARIANTS + (LEVERS if self.detail_sigma else ())

    @property
    def augmented_iterations(self) -> int:
        return int(round(self.iterations / (self.schedule.start + (1 - self.schedule.start) * (1 - self.schedule.share))))

    def record(self) -> dict[str, Any]:
        """The plan as a report records it, the schedule's settings among the plan's own."""
        s = self.schedule
        return {"iterations": self.iterations, "seeds": self.seeds, "start": s.start, "share": s.share,
                "refresh": s.refresh, "pool": s.pool, "weight": s.weight, "detail_sigma": self.detail_sigma,
                "mask": s.mask, "coverage": self.coverage, "pose_noise": self.pose_noise, "reach": self.reach,
                "poses": self.poses, "video_side": self.video_side if self.poses == "fit" else None,
                "augmented_iterations": self.augmented_iterations}


@dataclass(frozen=True)
class AblationBenchConfig:
    out: str | Path = OUT  # the report folder: models, runs, subjects and figures go in it
    corpus: str | Path = option("out/corpus", metavar="DIR", help="the corpus folder, built when absent")
    size: int = option(128, check=integer(2), help="image side of a corpus built here, pixels")
    subjects: int = option(10, check=integer(1), help="training subjects of a corpus built here")
    heldout: int = option(3, check=integer(1), help="held-out subjects of a corpus built here")
    baseline_frames: str = option("all", metavar="VARIANT",
                                  help="the one corpus variant the Refiners and the Examiner train on (all or subset)")
    style: str = option("plain", choices=STYLES, help="the synth style of a corpus built here")
    refiner_steps: int = option(1000, check=integer(1), help="training steps of each Refiner")
    refiner_size: str = option("compact", choices=REFINER_SIZE_NAMES, help="the Refiners' widths")
    examiner: str = option("examiner_nano", metavar="NAME", help="the Examiner's config name")
    examiner_steps: int = option(1000, check=integer(1), help="the Examiner's training steps")
    batch: int = option(4, check=integer(1), help="the models' training batch")
    crop: int = option(64, check=integer(1), help="the Refiners' training crop side, pixels")
    plan: AblationPlan = field(default_factory=AblationPlan)  # the avatar runs
    variants: tuple[str, ...] | None = option(None, sep=",", metavar="NAMES", help="train only these rows "
                                              "(comma-separated); the others are reported when finished")
    ablation_subjects: tuple[str, ...] | None = option(None, sep=",", metavar="NAMES",
                                                       help="held-out subjects of the corpus, comma-separated "
                                                            "(default: all of them)")
    training: bool = option(True, help="train what is missing (--no-training: report the finished runs, train nothing)")
    jobs: int = option(1, check=integer(1), help="avatar runs trained at once, each in its own process with an equal "
                                                 "share of the cores")

    def __post_init__(self) -> None:
        check_path(self, "out")
        check_path(self, "corpus")
        check_options(self)
        if self.baseline_frames not in ("all", "subset"):
            raise ValueError(f"baseline_frames: ablation trains on one corpus variant, 'all' or 'subset', "
                             f"got {self.baseline_frames!r}")
        for name in ("variants", "ablation_subjects"):
            if getattr(self, name) is not None:
                check_names(self, name)
