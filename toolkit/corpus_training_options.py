"""What ``trioman train-refiner`` and ``trioman train-examiner`` train (toolkit/corpus/training.py), each setting with
its option (runtime/options.py): the library's defaults and the commands' are these fields. Standard-library
imports only: the commands build their parsers from these fields.

It sits beside toolkit/corpus/, not in it, and not in toolkit/refiner/: the Refiner's config imports ``CONDITIONS``
from here, and toolkit/corpus/ imports the Refiner (training) and, through its baselines, the avatar's training, which
imports the Refiner too (toolkit's subpackages import one another without a cycle: tests/toolkit/loops/test_layering.py);
toolkit/refiner/'s ``__init__`` imports torch.
"""

from __future__ import annotations

from dataclasses import dataclass

from trioman.runtime.options import check_options, integer, option

# The paper's ablation (3.2.5): z_c alone; + z_t, the latent of a real frame near the view; + z_g, the body's
# normal map. "warp" / "warp+geo" take instead of the real frame the geometry-aligned reference
# (runtime/aligned.py) and refine it: views (aligned, coarse[, normal]) (docs/augmentation.md, "Refiner conditions").
CONDITIONS = ("none", "tex", "tex+geo", "warp", "warp+geo")
REFINER_SIZE_NAMES = ("compact", "default")  # corpus.training.REFINER_SIZES
BACKBONES = ("scratch", "sd-turbo")  # refiner.backbones.registered_backbones()
CORPUS_VARIANTS = ("all", "subset")


def _crop(value) -> str | None:
    return None if isinstance(value, int) and not isinstance(value, bool) and value >= 16 and value % 16 == 0 \
        else "must be a multiple of 16 (>= 16)"


@dataclass(frozen=True)
class TrainRefinerOptions:
    conditions: str = option("warp+geo", choices=CONDITIONS,
                             help="warp / warp+geo: refine the geometry-aligned reference (warp+geo measured best: "
                                  "docs/findings.md, 'Augmentation'); the paper's none / tex / tex+geo: a real frame "
                                  "near the view as reference")
    steps: int = option(1000, check=integer(1), help="training steps")
    batch: int = option(4, check=integer(1),
                        help="samples per process and step (the global batch is this times the process count)")
    crop: int = option(64, check=_crop, help="training crop side, a multiple of 16")
    size: str = option("compact", choices=REFINER_SIZE_NAMES, help="Refiner widths")
    baseline_frames: str = option("all", choices=CORPUS_VARIANTS, help="corpus variant")
    seed: int = option(0, check=integer(0), help="the seed of the weights and the samples")
    backbone: str = option("scratch", choices=BACKBONES,
                           help="sd-turbo: the paper's SD-Turbo backbone from --pretrained DIR (needs trioman[diffusion])")
    pretrained: str | None = option(None, metavar="DIR",
                                    help="local SD-Turbo folder in diffusers layout (never downloaded)")
    device: str = option("cpu", choices=("cpu", "cuda"),
                         help="cpu or cuda (under torchrun each process takes the GPU of its local rank)")
    mixed_precision: str = option("no", choices=("no", "bf16"), help="bf16 autocast (CUDA)")
    gradient_checkpointing: bool = option(False, help="recompute activations (sd-turbo)")

    def __post_init__(self) -> None:
        check_options(self)


@dataclass(frozen=True)
class TrainExaminerOptions:
    model: str = option("examiner_nano", help="config name: examiner_nano, examiner_tiny, examiner_small")
    steps: int = option(1000, check=integer(1), help="training steps")
    batch: int = option(4, check=integer(1),
                        help="samples per process and step (the global batch is this times the process count)")
    baseline_frames: str = option("all", choices=CORPUS_VARIANTS, help="corpus variant")
    seed: int = option(0, check=integer(0), help="the seed of the weights and the samples")
    pairing: str = option("contrast", choices=("contrast", "paper"),
                          help="training pairs: every sample's real and coarse pair, or the paper's random draw")
    validation_subjects: int = option(1, check=integer(0),
                                      help="hold out the last N training subjects and keep the step with the best AUROC "
                                           "on them (0: the last step)")
    validate_every: int = option(100, check=integer(1), help="steps between validations")
    device: str = option("cpu", choices=("cpu", "cuda"),
                         help="cpu or cuda (under torchrun each process takes the GPU of its local rank)")
    mixed_precision: str = option("no", choices=("no", "bf16"), help="bf16 autocast (CUDA)")
    lr: float = 3e-4  # the Examiner's learning rate (corpus.training.FitConfig's is the Refiner's)

    def __post_init__(self) -> None:
        check_options(self)
