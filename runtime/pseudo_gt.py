"""One augmentation step (paper 3.2.3-3.2.6), shared by online training and ``trioman augment``:
a source frame's Generator candidates -> pseudo-GT frames with their masks and per-pixel loss weights.

Stages (timed in ``seconds``): render (the caller's ``render`` callback: the torch avatar during
training, the numpy splat renderer in ``augment``), align (the geometry-aligned reference,
runtime/aligned.py), normal (the body normal map, for a Refiner conditioned on geometry), refine,
examine. What the pseudo-GT image holds is ``PseudoConfig.kind`` (docs/augmentation.md, "Pseudo-GT").
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Callable, NamedTuple, Protocol, Sequence

import numpy as np

from trioman.runtime.aligned import Aligned, Aligner
from trioman.runtime.generator import Candidate, keep_detail
from trioman.runtime.onnx_models import ALIGNED_CONDITIONS
from trioman.runtime.normal_map import body_normal_map
from trioman.runtime.pseudo_kinds import KINDS, MASKS, STAGES
from trioman.runtime.skeleton import SkinnedMesh

__all__ = ["KINDS", "MASKS", "STAGES", "PseudoConfig", "Source", "PseudoFrames", "make_pseudo_frames", "needs_aligner"]


class RefinerLike(Protocol):
    conditions: str

    def refine(self, coarse: np.ndarray, reference: np.ndarray | None = None,
               normal: np.ndarray | None = None) -> np.ndarray: ...


class ExaminerLike(Protocol):
    def score(self, candidates: np.ndarray, reference: np.ndarray) -> np.ndarray: ...


@dataclass(frozen=True)
class PseudoConfig:
    kind: str = "coarse"  # one of KINDS
    mask: str = "carried"  # one of MASKS
    unknown_weight: float = 0.0  # kinds "aligned", "truth_seen": loss weight of body pixels that no real pixel reached
    detail_sigma: float = 0.0  # > 0: keep only the Refiner's detail (runtime.generator.keep_detail)
    threshold: float | None = None  # examined: drop the best candidate when its score is below
    keep_carried: bool = False  # refined / examined: carried real pixels stay, the Refiner's output only elsewhere

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"kind: expected one of {KINDS}, got {self.kind!r}")
        if self.mask not in MASKS:
            raise ValueError(f"mask: expected one of {MASKS}, got {self.mask!r}")
        for name in ("unknown_weight", "detail_sigma"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
                raise ValueError(f"{name}: must be a finite number >= 0, got {v!r}")
        if self.unknown_weight > 1:
            raise ValueError(f"unknown_weight: must lie in [0, 1], got {self.unknown_weight!r}")
        if not isinstance(self.keep_carried, bool):
            raise ValueError(f"keep_carried: must be true or false, got {self.keep_carried!r}")
        if self.keep_carried and not self.refined:
            raise ValueError(f"keep_carried: needs kind 'refined' or 'examined' (a Refiner to fill what was not "
                             f"carried), got kind {self.kind!r}")

    @property
    def refined(self) -> bool:
        return self.kind in ("refined", "examined")

    @property
    def from_truth(self) -> bool:
        """Whether the pseudo-GT is the subject's own renderer at the draw (synthetic subjects only)."""
        return self.kind in ("truth", "truth_seen")


def needs_aligner(cfg: PseudoConfig, refiner_conditions: str | None = None) -> bool:
    """Whether the step needs the aligned reference: kinds aligned and truth_seen, the carried mask (the truth
    brings its own), carried pixels kept, or a Refiner conditioned on it."""
    return (cfg.kind in ("aligned", "truth_seen") or (cfg.mask == "carried" and not cfg.from_truth) or cfg.keep_carried
            or (cfg.refined and refiner_conditions in ALIGNED_CONDITIONS))


class Source(NamedTuple):
    """The source frame T of the candidates."""

    position: int  # its position in the Aligner's views
    real: np.ndarray  # [H, W, 3] I^T over the background
    K: np.ndarray  # [3, 3]
    background: np.ndarray  # [3]


@dataclass
class PseudoFrames:
    """Every candidate's pseudo-GT; ``kept`` lists the candidates to train on."""

    images: np.ndarray  # [C, H, W, 3] over the background where mask < 1
    masks: np.ndarray  # [C, H, W] in [0, 1]
    weights: np.ndarray  # [C, H, W] per-pixel loss weight in [0, 1]
    kept: list[int]
    chosen: int | None = None  # the Examiner's pick (None without an Examiner)
    scores: list[float] | None = None
    coverage: list[float] = field(default_factory=list)  # share of body pixels holding carried real pixels


def _tick(seconds: dict[str, float] | None, stage: str, t: float) -> float:
    now = time.perf_counter()
    if seconds is not None:
        seconds[stage] = seconds.get(stage, 0.0) + now - t
    return now


def make_pseudo_frames(
    candidates: Sequence[Candidate],
    source: Source,
    render: Callable[[Candidate], tuple[np.ndarray, np.ndarray]],
    cfg: PseudoConfig,
    *,
    body: SkinnedMesh | None = None,
    aligner: Aligner | None = None,
    refiner: RefinerLike | None = None,
    examiner: ExaminerLike | None = None,
    truth: Callable[[Candidate, np.ndarray], tuple[np.ndarray, np.ndarray]] | None = None,
    seconds: dict[str, float] | None = None,
) -> PseudoFrames:
    """Pseudo-GT frames of ``candidates`` (module doc).

    render(c) -> (rgb [H, W, 3] over the background, alpha [H, W]); truth(c, K) -> (rgb [H, W, 3] on black,
    mask [H, W]) (kinds "truth", "truth_seen"). Kinds refined / examined need ``refiner`` (and ``body`` for its geometry
    condition), examined with more than one candidate or a threshold ``examiner``; ``aligner`` whenever
    ``needs_aligner``.
    """
    if cfg.refined and refiner is None:
        raise ValueError(f"refiner: kind {cfg.kind!r} needs a Refiner")
    if cfg.from_truth and truth is None:
        raise ValueError(f"truth: kind {cfg.kind!r} needs the subject's own renderer (synthetic subjects only)")
    conditions = refiner.conditions if cfg.refined else None
    align = needs_aligner(cfg, conditions)
    if align and aligner is None:
        raise ValueError(f"aligner: kind {cfg.kind!r} with mask {cfg.mask!r}"
                         f"{f' and a {conditions!r} Refiner' if conditions else ''} needs an Aligner")
    t = time.perf_counter()
    bg = np.asarray(source.background, np.float32)
    K = np.asarray(source.K, np.float64)
    renders = [render(c) for c in candidates]
    coarse = np.stack([np.asarray(r, np.float32) for r, _ in renders])
    alpha = np.stack([np.asarray(a, np.float32) for _, a in renders])
    t = _tick(seconds, "render", t)
    aligned: list[Aligned | None] = [None] * len(candidates)
    if align:
        aligned = [aligner.align(source.position, c.pose, c.trans, c.viewmat, K, coarse[k])
                   for k, c in enumerate(candidates)]
        t = _tick(seconds, "align", t)
    content = coarse
    if cfg.kind == "aligned" or conditions in ALIGNED_CONDITIONS:
        content = np.stack([np.where(a.valid[..., None], a.rgb, x) for a, x in zip(aligned, coarse)])
    if cfg.refined:
        normal = None
        if conditions.endswith("+geo"):
            if body is None:
                raise ValueError("body: a Refiner with the geometry condition needs the subject's body mesh")
            H, W = coarse.shape[1:3]
            normal = np.stack([body_normal_map(body, c.pose, c.trans, c.viewmat, K, W, H).rgb
                               for c in candidates]).astype(np.float32)
            t = _tick(seconds, "normal", t)
        reference = content if conditions in ALIGNED_CONDITIONS else None if conditions == "none" else np.ascontiguousarray(
            np.broadcast_to(np.asarray(source.real, np.float32), coarse.shape))
        content = np.asarray(refiner.refine(coarse, reference=reference, normal=normal), dtype=np.float32)
        if content.shape != coarse.shape:
            raise ValueError(f"refiner: output shape {list(content.shape)}, expected {list(coarse.shape)}")
        content = np.clip(content, 0.0, 1.0)
        if cfg.detail_sigma > 0:
            content = keep_detail(coarse, content, cfg.detail_sigma)
        if cfg.keep_carried:
            content = np.stack([np.where(a.valid[..., None], a.rgb, x) for a, x in zip(aligned, content)])
        t = _tick(seconds, "refine", t)
    chosen, scores, kept = None, None, list(range(len(candidates)))
    if cfg.kind == "examined" and examiner is not None and (len(candidates) > 1 or cfg.threshold is not None):
        s = np.asarray(examiner.score(content, np.asarray(source.real, np.float32)), dtype=np.float64).reshape(-1)
        scores = [float(x) for x in s]
        chosen = int(np.argmax(s))
        kept = [chosen] if cfg.threshold is None or s[chosen] >= cfg.threshold else []
        t = _tick(seconds, "examine", t)
    elif cfg.kind == "examined":
        kept = [0]
    if cfg.from_truth:
        pairs = [truth(c, K) for c in candidates]
        masks = np.stack([np.asarray(m, np.float32) for _, m in pairs])
        images = np.stack([np.asarray(r, np.float32) for r, _ in pairs]) + (1.0 - masks)[..., None] * bg
    else:
        masks = np.stack([a.silhouette for a in aligned]) if cfg.mask == "carried" else alpha
        images = content * masks[..., None] + (1.0 - masks)[..., None] * bg
    weights = np.ones_like(masks)
    if cfg.kind in ("aligned", "truth_seen"):
        for k, a in enumerate(aligned):
            weights[k][a.body & ~a.valid] = cfg.unknown_weight
    coverage = [a.coverage for a in aligned if a is not None]
    return PseudoFrames(np.clip(images, 0.0, 1.0).astype(np.float32), masks.astype(np.float32), weights.astype(np.float32),
                        kept, chosen, scores, coverage)
