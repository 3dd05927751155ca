"""The settings of online augmentation (toolkit/train/augmentation.py), each with its option (trioman/options.py).

Standard-library imports only: ``trioman train`` and ``trioman bench`` build their options from these fields, so
the library's defaults are the commands' defaults. The schedule's defaults (``start``, ``refresh``, ``pool``,
``share``, ``weight``) and ``keep_carried`` are the ones the ablation measured best (docs/augmentation.md,
"Defaults and their evidence").
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from trioman.runtime.options import check_options, integer, number, option
from trioman.runtime.pretrained import NONE, SHIPPED
from trioman.runtime.pseudo_kinds import KINDS, MASKS

MODES = KINDS  # what a pseudo frame holds (runtime/pseudo_kinds.py)
WITH_REFINER = ("refined", "examined")
# what `--augment` alone runs: the best kind measured with what ships, the one without a model (`--refiner none`);
# the shipped Refiner and Examiner (`--augment examined`) measured below it on the demo's subject (docs/models.md)
ALONE = "aligned"


def _texture(value: Any) -> str | None:
    ok = isinstance(value, int) and not isinstance(value, bool) and (value == 0 or 16 <= value <= 4096)
    return None if ok else "0 (off) or the fused texture's side in texels, 16 to 4096"


@dataclass(frozen=True)
class AugmentConfig:
    mode: str = option("coarse", flag="--augment", choices=MODES, const=ALONE, default_text="off; --augment "
                       "alone: aligned, the best kind measured (docs/models.md)",
                       help="pseudo-GT frames made during training: the avatar's own renders at Generator poses and "
                            "cameras (coarse), with real pixels carried through the body mesh where known (aligned), "
                            "refined by --refiner (refined), the best of --per-frame refined candidates by --examiner "
                            "(examined), or the subject's own renderer (truth: synthetic subjects only, the ceiling; "
                            "truth_seen: the same only where a training frame saw the surface)")
    mask: str = option("carried", flag="--augment-mask", choices=MASKS,
                       help="a pseudo frame's mask: the body mesh plus the source frame's mask carried to the draw "
                            "(carried) or the avatar render's own alpha (alpha, the paper's)")
    unknown_weight: float = option(0.0, flag="--augment-unknown-weight", check=number(0),
                                   help="--augment aligned|truth_seen: loss weight of body pixels no real pixel reached")
    align_sources: int = option(3, flag="--augment-sources", check=integer(1),
                                help="training frames the aligned reference fuses per draw")
    align_texture: int = option(0, flag="--augment-texture", metavar="TEXELS", check=_texture,
                                help="take the aligned reference's colour from a texture of this side fused from every "
                                     "training frame wherever its texels were seen (runtime/texture_fusion.py; 0: "
                                     "carried pixels only)")
    refiner: str | None = option(None, metavar="RUN|CKPT|ONNX|none", default_text="the shipped one with refined|examined",
                                 help="Refiner: train-refiner run, checkpoint or .onnx; none: no model, the aligned kind")
    examiner: str | None = option(None, metavar="RUN|CKPT|ONNX|none", default_text="the shipped one with examined",
                                  help="Examiner: train-examiner run, checkpoint or .onnx; none: every candidate kept "
                                       "(the refined kind)")
    per_frame: int | None = option(None, check=integer(1), default_text="2 with an Examiner, else 1",
                                   help="Generator candidates per source frame")
    threshold: float | None = option(None, check=number(0, 1),
                                     help="drop the Examiner's best candidate below this score, in [0, 1]")
    start: float = option(0.2, flag="--augment-start", check=number(0, 1, hi_open=True),
                          help="fraction of the iterations on real frames only first (the warm-up)")
    refresh: int = option(25, flag="--augment-refresh", check=integer(1), help="steps between rebuilds of the pseudo-GT pool")
    pool: int = option(32, flag="--augment-pool", check=integer(1), help="pseudo-GT frames per rebuild")
    share: float = option(0.5, flag="--augment-share", check=number(0, 1, lo_open=True),
                          help="share of the steps after the warm-up on pseudo-GT frames")
    weight: float = option(1.0, flag="--augment-weight", check=number(0), help="loss weight of a pseudo-GT frame")
    # > 0: keep only the Refiner's detail, its change minus that change blurred by this many pixels
    # (runtime.generator.keep_detail); the avatar then never learns the Refiner's colour shift, which the online loop
    # would compound (each rebuild refines renders of an avatar trained on the previous refinements)
    detail_sigma: float = option(0.0, flag="--augment-detail-sigma", metavar="PX", check=number(0),
                                 help="keep only the Refiner's detail: its change minus that change blurred by PX "
                                      "pixels, so the avatar does not learn the Refiner's colour shift (0: the refined "
                                      "frame as it is)")
    keep_carried: bool | None = option(None, flag="--augment-keep-carried", default_text="on with a Refiner",
                                       help="--augment refined|examined: keep the real pixels carried to the draw and "
                                            "take the Refiner's output only where nothing was carried")
    pose_sigma: dict[str, float] = field(default_factory=dict)  # Generator pose sigmas per group (defaults otherwise)
    camera: tuple[float, float, float] | None = None  # Generator (azimuth, elevation, log-distance) sigmas; None: defaults

    def __post_init__(self) -> None:
        check_options(self)
        self._resolve_models()
        needs_refiner = self.mode in WITH_REFINER
        if self.keep_carried is None:  # the default: on wherever there is a Refiner to fill the rest
            object.__setattr__(self, "keep_carried", needs_refiner)
        if needs_refiner and not self.refiner:
            raise ValueError(f"refiner: `mode` {self.mode} needs a Refiner (a run folder, checkpoint or .onnx)")
        if self.mode == "examined" and not self.examiner:
            raise ValueError("examiner: `mode` examined needs an Examiner (a run folder, checkpoint or .onnx)")
        if self.mode != "examined" and self.examiner:
            raise ValueError(f"examiner: `mode` {self.mode} does not use an Examiner (use `mode` examined)")
        if not needs_refiner and self.refiner:
            raise ValueError(f"refiner: `mode` {self.mode} does not use a Refiner (use `mode` refined or examined)")
        if self.mode != "examined" and (self.per_frame or 1) != 1:
            raise ValueError(f"per_frame: {self.per_frame} candidates need an Examiner to choose (`mode` examined)")
        if self.threshold is not None and self.mode != "examined":
            raise ValueError("threshold: needs `mode` examined")
        if self.detail_sigma > 0 and not needs_refiner:
            raise ValueError("detail_sigma: needs a Refiner (`mode` refined or examined)")
        if self.keep_carried and not needs_refiner:
            raise ValueError("keep_carried: needs a Refiner to fill what was not carried (`mode` refined or examined)")
        if self.align_texture and self.mode not in ("aligned", *WITH_REFINER):
            raise ValueError(f"align_texture: `mode` {self.mode} takes no colour from the aligned reference "
                             "(use `mode` aligned, refined or examined)")
        self.pseudo()  # validates the mask and weights
        self.generator()  # validates the sigmas

    def _resolve_models(self) -> None:
        """``none`` and the shipped models: a kind that needs a Refiner without ``refiner`` gets the shipped one
        (``examined`` the shipped Examiner too); ``refiner`` none turns it into the aligned kind, ``examiner`` none
        ``examined`` into ``refined``. The fields then hold paths (the run records which file it used)."""
        from trioman.runtime.pretrained import resolve_model

        def set_(name: str, value: Any) -> None:  # a frozen dataclass
            object.__setattr__(self, name, value)

        if self.mode not in WITH_REFINER:
            for name in ("refiner", "examiner"):
                if getattr(self, name) == NONE:
                    set_(name, None)
            return
        if self.refiner == NONE:
            if self.examiner not in (None, NONE):
                raise ValueError("examiner: chooses among refined candidates; `refiner` none gives the aligned kind")
            set_("mode", ALONE)
            set_("refiner", None)
            set_("examiner", None)
            return
        if self.examiner == NONE:
            set_("mode", "refined")
            set_("examiner", None)
        if self.refiner in (None, SHIPPED):
            set_("refiner", str(resolve_model(SHIPPED, "refiner")))
        if self.mode == "examined" and self.examiner in (None, SHIPPED):
            set_("examiner", str(resolve_model(SHIPPED, "examiner")))

    @property
    def candidates(self) -> int:
        return self.per_frame or (2 if self.mode == "examined" else 1)

    def generator(self) -> Any:
        """The Generator's config (runtime.generator.GeneratorConfig) of ``pose_sigma`` and ``camera``."""
        from trioman.runtime.generator import GeneratorConfig

        kw: dict[str, Any] = {"pose_sigma": dict(self.pose_sigma)}
        if self.camera is not None:
            kw.update(azimuth_sigma=self.camera[0], elevation_sigma=self.camera[1], distance_sigma=self.camera[2])
        return GeneratorConfig(**kw)

    def pseudo(self) -> Any:
        """The shared augmentation step's config (runtime.pseudo_gt.PseudoConfig)."""
        from trioman.runtime.pseudo_gt import PseudoConfig

        return PseudoConfig(kind=self.mode, mask=self.mask, unknown_weight=self.unknown_weight,
                            detail_sigma=self.detail_sigma, threshold=self.threshold,
                            keep_carried=self.keep_carried)

    def start_step(self, iterations: int) -> int:
        return int(round(self.start * iterations))

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "AugmentConfig":
        """The inverse of ``dataclasses.asdict``: a run record's settings (each recorded, so later defaults do not
        change a recorded run)."""
        d = dict(d)
        d.setdefault("mask", "alpha")  # runs recorded before the mask was a setting used the render's alpha
        d.setdefault("keep_carried", False)  # runs recorded before it was a setting kept nothing
        if d.get("camera") is not None:
            d["camera"] = tuple(d["camera"])
        return cls(**d)
