"""The configs of the ``trioman bench`` targets (bench/ablation_config.py has the ablation's), each field a target's
setting with its option (runtime/options.py): ``trioman bench TARGET`` builds its options from them, so a target's
defaults are its command's. Where the report goes (``out``) is the command's own ``--out``. Standard-library imports
only (the command builds its parsers from them without torch)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

from trioman.bench.common import check_names, check_path
from trioman.runtime.options import check_options, integer, number, option
from trioman.toolkit.corpus_training_options import BACKBONES, CORPUS_VARIANTS, REFINER_SIZE_NAMES
from trioman.toolkit.synth.config import CAPTURES, STYLES
from trioman.toolkit.train.config import PRESETS

OUT = "out/bench"  # the report folder of every target


@dataclass(frozen=True)
class BenchConfig:
    """What every target's config checks, in this order: its folder fields (``PATHS``; ``OPTIONAL_PATHS`` may be
    None), every option, its name lists (``NAMES``), then ``check``, the target's own rules."""

    PATHS: ClassVar[tuple[str, ...]] = ()
    OPTIONAL_PATHS: ClassVar[tuple[str, ...]] = ()
    NAMES: ClassVar[tuple[str, ...]] = ()

    def __post_init__(self) -> None:
        for name in self.PATHS:
            check_path(self, name)
        for name in self.OPTIONAL_PATHS:
            check_path(self, name, optional=True)
        check_options(self)
        for name in self.NAMES:
            check_names(self, name)
        self.check()

    def check(self) -> None:
        """The target's rules beyond its options: ValueError naming the field."""


@dataclass(frozen=True)
class ReportConfig(BenchConfig):
    """A target whose work goes in its report folder ``out`` (the command's ``--out``)."""

    out: str | Path = OUT
    PATHS: ClassVar[tuple[str, ...]] = ("out",)


@dataclass(frozen=True)
class SynthBenchConfig(BenchConfig):
    """``bench synth``: one subject's synthesis, timed."""

    seed: int = option(0, check=integer(0), help="the subject's seed")
    size: int = option(256, check=integer(1), help="image side, pixels (the long side with --aspect)")
    frames: int = option(300, check=integer(1), help="subject frames")
    style: str = option("plain", choices=STYLES, help="the subject's style (toolkit/synth/subject.py)")
    aspect: float = option(1.0, metavar="W/H", check=number(0, lo_open=True),
                           help="image width / height, e.g. 0.5625 for a portrait phone video")


@dataclass(frozen=True)
class TrainBenchConfig(ReportConfig):
    """``bench train``: the subject, the runs and the figures go in ``out``."""

    NAMES: ClassVar[tuple[str, ...]] = ("presets",)

    seed: int = option(0, check=integer(0), help="the subject's seed")
    size: int = option(256, check=integer(2),
                       help="the subject's image side, pixels (the rasterizer and the step profile also run at half)")
    frames: int = option(120, check=integer(1), help="subject frames")
    presets: tuple[str, ...] = option(("quick", "full"), sep=",", choices=tuple(PRESETS), metavar="NAMES",
                                      help="presets to run, each from scratch, comma-separated")
    iterations: int | None = option(None, check=integer(1), help="every preset's iterations (default: the preset's)")
    full_iterations: int | None = option(None, check=integer(1),
                                         help="the full preset's iterations when --iterations is not given (default: "
                                              "the preset's)")
    eval_every: int = option(250, check=integer(1),
                             help="iterations between the evaluations of both splits (the runs' checkpoint interval)")
    training: bool = option(True, help="train the presets (--no-training: only the rasterizer timings and the step "
                                       "profile)")
    repeats: int = option(5, check=integer(1), help="timed steps of the step profile")
    threads: int | None = option(None, check=integer(1), help="the step profile's torch threads (default 1 and 2)")


@dataclass(frozen=True)
class RenderBenchConfig(BenchConfig):
    """``bench render``: the numpy and torch renderers against the float64 oracle."""

    OPTIONAL_PATHS: ClassVar[tuple[str, ...]] = ("avatar_run",)

    size: int = option(256, check=integer(2), help="image side, pixels: the renderers run at it and at twice it, the "
                                                   "oracle at half (at most 128)")
    avatar_run: str | Path | None = option(None, metavar="RUN",
                                           help="a trained run folder (default: the untrained default avatar)")


@dataclass(frozen=True)
class ModelsBenchConfig(ReportConfig):
    """``bench models``: the runs go in ``out/runs``, the score figure beside the report."""

    PATHS: ClassVar[tuple[str, ...]] = ("out", "corpus")
    OPTIONAL_PATHS: ClassVar[tuple[str, ...]] = ("pretrained",)

    corpus: str | Path = option("out/corpus", metavar="DIR", help="the corpus folder, built when absent")
    subjects: int = option(10, check=integer(1), help="training subjects when building the corpus")
    heldout: int = option(2, check=integer(1), help="held-out subjects when building the corpus")
    size: int = option(128, check=integer(1), help="the corpus's image side, pixels, when building it")
    refiner_steps: int = option(1000, check=integer(1), help="Refiner training steps per condition")
    refiner_size: str = option("compact", choices=REFINER_SIZE_NAMES, help="the Refiner's widths")
    backbone: str = option("scratch", choices=BACKBONES, help="the Refiner's backbone")
    pretrained: str | Path | None = option(None, metavar="DIR", help="a local SD-Turbo folder for --backbone sd-turbo "
                                                                     "(never downloaded)")
    crop: int = option(64, check=integer(1), help="Refiner training crop side, pixels")
    examiner: str = option("examiner_nano", metavar="NAME", help="the Examiner's config name")
    examiner_steps: int = option(1000, check=integer(1), help="Examiner training steps")
    batch: int = option(4, check=integer(1), help="training batch size of both models")
    baseline_frames: tuple[str, ...] = option(("all",), sep=",", choices=CORPUS_VARIANTS, metavar="NAMES",
                                              help="corpus variants of the coarse frames, e.g. all,subset (each but "
                                                   "all adds a tex+geo Refiner)")

    def check(self) -> None:
        if not isinstance(self.examiner, str) or not self.examiner:
            raise ValueError(f"examiner: expected an Examiner config name, got {self.examiner!r}")


@dataclass(frozen=True)
class DeployBenchConfig(ReportConfig):
    """``bench deploy``: the ONNX export, the augment run and the figure go in ``out``."""

    PATHS: ClassVar[tuple[str, ...]] = ("out", "corpus", "models")
    OPTIONAL_PATHS: ClassVar[tuple[str, ...]] = ("avatar_run",)

    corpus: str | Path = option("out/corpus", metavar="DIR",
                                help="the corpus of the `bench models` report (its held-out test frames)")
    models: str | Path = option("out/bench_models", metavar="DIR",
                                help="the `bench models` report folder whose trained runs are exported")
    frames: int | None = option(None, check=integer(1), help="held-out test frames measured (default: all of them)")
    avatar_run: str | Path | None = option(None, metavar="RUN", help="the renderer rows' trained run folder (default: "
                                                                     "the untrained default avatar)")
    size: int = option(256, check=integer(2), help="the renderer rows' image side, pixels")
    repeats: int = option(5, check=integer(1), help="timed calls per variant (the best counts)")
    threads: int | None = option(None, check=integer(1), help="onnxruntime intra-op threads (default: onnxruntime's)")
    augment_frames: int = option(8, check=integer(1), help="source frames of the augment run")


@dataclass(frozen=True)
class FramesBenchConfig(ReportConfig):
    """``bench frames``: the generated subject (reused when there) and the run go in ``out``."""

    frames: int = option(1500, check=integer(1), help="frames of the generated subject")
    size: int = option(1024, check=integer(1), help="its image side, pixels")
    iterations: int = option(20, check=integer(1), help="training iterations")


@dataclass(frozen=True)
class StabilityBenchConfig(ReportConfig):
    """``bench stability``: the training cases' runs and the exported models go in ``out``."""

    seeds: int = option(2, check=integer(1), help="extreme scenes drawn")
    iterations: int = option(30, check=integer(1), help="training steps of each training case")


@dataclass(frozen=True)
class ScaleBenchConfig(BenchConfig):
    """``bench scale``: samples/s at 1 and 2 processes."""

    size: int = option(64, check=integer(1), help="the random triplets' image side, pixels (a multiple of the compact "
                                                  "Refiner's downsampling)")
    batch: int = option(4, check=integer(1), help="samples per process and step")
    iterations: int = option(20, check=integer(1), help="timed steps per series")
    seed: int = option(0, check=integer(0), help="the Refiner's initial weights and the triplets")

    def check(self) -> None:
        from trioman.toolkit.corpus.training import REFINER_SIZES
        from trioman.toolkit.refiner import RefinerConfig

        step = RefinerConfig(conditions="tex+geo", **REFINER_SIZES["compact"]).total_downsample
        if self.size % step:
            raise ValueError(f"size: must be a multiple of {step} (the compact Refiner's downsampling), got {self.size}")


@dataclass(frozen=True)
class FitBenchConfig(ReportConfig):
    """``bench fit``: subjects, videos and fits go in ``out/fit_work``."""

    seed: int = option(1004, check=integer(0),
                       help="the first subject's seed (the ablation's held-out subjects are 1004-1006)")
    subjects: int = option(3, check=integer(1), help="subjects")
    size: int = option(540, check=integer(1), help="the frames' long side, pixels")
    frames: int = option(375, check=integer(1), help="subject frames; the video holds the training split (four fifths)")
    coverage: float = option(1.0, metavar="FRACTION", check=number(0, 1, lo_open=True),
                             help="share of a full turn the video's turn spans")
    capture: str = option("turn", choices=CAPTURES, help="the video's motion: turning in place, or a few steps first")
    style: str = option("realistic", choices=STYLES, help="the subjects' style")
    focal: str = option("prior", choices=("prior", "truth"),
                        help="the fit refines a phone's focal (prior) or is given the subject's (truth)")
    iterations: int | None = option(None, check=integer(1), help="the fit's iterations over every frame and on the "
                                                                 "keyframes (default: trioman fit's)")
    avatar_iterations: int = option(0, check=integer(0), help="> 0: also trains the avatar on the fit and on the true "
                                                              "poses this long (the cost of fitting)")


@dataclass(frozen=True)
class LandmarksBenchConfig(ReportConfig):
    """``bench landmarks``: the subjects go in ``out/landmarks_work``."""

    seed: int = option(2000, check=integer(0), help="the calibration subjects' first seed (apart from the ablation's "
                                                    "and bench fit's 1004-1006)")
    subjects: int = option(4, check=integer(1), help="calibration subjects")
    size: int = option(540, check=integer(1), help="their image side, pixels")
    frames: int = option(60, check=integer(1), help="frames of each subject")


@dataclass(frozen=True)
class AugmentCostBenchConfig(ReportConfig):
    """``bench augment-cost``: the subjects and the runs go in ``out``."""

    size: int | None = option(None, check=integer(16), help="one image side, pixels (default: 128 and 256)")
    frames: int = option(96, check=integer(6), help="subject frames")
    iterations: int = option(300, check=integer(1), help="training steps of both runs")
    seed: int = option(0, check=integer(0), help="the subject's seed")
