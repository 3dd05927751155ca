"""Online augmentation (paper 3.2.3-3.2.7): pseudo-GT frames made during the avatar's own optimisation.

After a warm-up of ``start`` x iterations, every ``refresh`` steps the pool of pseudo-GT frames is
rebuilt; each of its ``pool`` entries is made as follows:

    source    a training frame T (real image I^T over the subject's background)
    generate  the Generator draws ``per_frame`` candidates (pose + camera about the subject)
    render    the current avatar at each candidate (no grad), over the subject's background: the
              coarse frame I_c and its alpha
    normal    the body normal map at each candidate (only for a Refiner conditioned on geometry)
    refine    Refiner(I_c, reference I^T, normal) -> I_r (mode "refined" / "examined")
    examine   Examiner score of each I_r against I^T; the best is kept, and dropped below
              ``threshold`` (mode "examined"; no call for a single candidate without a threshold)

Mode "coarse" keeps the rendered candidate itself (the paper's "+ Generator" row). A pseudo frame
is supervised like a real one with the render's alpha as its mask (its colour premultiplied by that
alpha), with loss weight ``weight``; each step after the warm-up trains on a pool frame with
probability ``share``. The pool and this module's random state live in the checkpoints, so a
resumed run equals an uninterrupted one.
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from trioman.runtime.formats import Subject
from trioman.runtime.generator import GeneratorConfig, keep_detail, sample
from trioman.runtime.normal_map import body_normal_map
from trioman.toolkit.avatar.model import GaussianAvatar
from trioman.toolkit.render import rasterize
from trioman.toolkit.train.data import FrameSet

MODES = ("coarse", "refined", "examined")
STAGES = ("generate", "render", "normal", "refine", "examine")
_POOL_KEYS = ("images", "masks", "poses", "trans", "K", "viewmat")


@dataclass(frozen=True)
class AugmentConfig:
    mode: str = "coarse"  # one of MODES
    refiner: str | None = None  # run folder, checkpoint or .onnx (modes refined, examined)
    examiner: str | None = None  # run folder, checkpoint or .onnx (mode examined)
    per_frame: int | None = None  # Generator candidates per source frame; None: 2 with an Examiner, else 1
    threshold: float | None = None  # Examiner score below which the best candidate is dropped
    start: float = 0.4  # fraction of the iterations trained on real frames only (warm-up)
    refresh: int = 100  # steps between rebuilds of the pseudo-GT pool
    pool: int = 8  # pseudo-GT frames per rebuild
    share: float = 0.5  # probability that a step after the warm-up trains on a pool frame
    weight: float = 1.0  # photometric loss weight of a pseudo-GT frame
    detail_sigma: float = 0.0  # > 0: keep only the Refiner's detail, its change minus that change blurred by this
    # many pixels (runtime.generator.keep_detail); the avatar then never learns the Refiner's colour shift, which the
    # online loop would compound (each rebuild refines renders of an avatar trained on the previous refinements)
    pose_sigma: dict[str, float] = field(default_factory=dict)  # Generator pose sigmas per group (defaults otherwise)
    camera: tuple[float, float, float] | None = None  # Generator (azimuth, elevation, log-distance) sigmas; None: defaults

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ValueError(f"augment: expected one of {MODES}, got {self.mode!r}")
        if self.mode != "coarse" and not self.refiner:
            raise ValueError(f"refiner: --augment {self.mode} needs a Refiner (--refiner RUN|CKPT|ONNX)")
        if self.mode == "examined" and not self.examiner:
            raise ValueError("examiner: --augment examined needs an Examiner (--examiner RUN|CKPT|ONNX)")
        if self.mode != "examined" and self.examiner:
            raise ValueError(f"examiner: --augment {self.mode} does not use an Examiner (use --augment examined)")
        if self.mode == "coarse" and self.refiner:
            raise ValueError("refiner: --augment coarse does not use a Refiner (use --augment refined or examined)")
        if self.per_frame is not None and (isinstance(self.per_frame, bool) or not isinstance(self.per_frame, int)
                                           or self.per_frame < 1):
            raise ValueError(f"per_frame: must be an integer >= 1, got {self.per_frame!r}")
        if self.mode != "examined" and (self.per_frame or 1) != 1:
            raise ValueError(f"per_frame: {self.per_frame} candidates need an Examiner to choose (--augment examined)")
        if self.threshold is not None and (self.mode != "examined" or not 0.0 <= self.threshold <= 1.0):
            raise ValueError(f"threshold: needs --augment examined and a value in [0, 1], got {self.threshold!r}")
        if not 0.0 <= self.start < 1.0:
            raise ValueError(f"augment_start: must lie in [0, 1), got {self.start!r}")
        for name in ("refresh", "pool"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise ValueError(f"augment_{name}: must be an integer >= 1, got {v!r}")
        if not 0.0 < self.share <= 1.0:
            raise ValueError(f"augment_share: must lie in (0, 1], got {self.share!r}")
        if not (math.isfinite(self.weight) and self.weight >= 0):
            raise ValueError(f"augment_weight: must be a finite number >= 0, got {self.weight!r}")
        if not (isinstance(self.detail_sigma, (int, float)) and math.isfinite(self.detail_sigma) and self.detail_sigma >= 0):
            raise ValueError(f"augment_detail_sigma: must be a finite number >= 0 (pixels), got {self.detail_sigma!r}")
        if self.detail_sigma > 0 and self.mode == "coarse":
            raise ValueError("augment_detail_sigma: needs a Refiner (--augment refined or examined)")
        self.generator()  # validates the sigmas

    @property
    def candidates(self) -> int:
        return self.per_frame or (2 if self.mode == "examined" else 1)

    def generator(self) -> GeneratorConfig:
        kw: dict[str, Any] = {"pose_sigma": dict(self.pose_sigma)}
        if self.camera is not None:
            kw.update(azimuth_sigma=self.camera[0], elevation_sigma=self.camera[1], distance_sigma=self.camera[2])
        return GeneratorConfig(**kw)

    def start_step(self, iterations: int) -> int:
        return int(round(self.start * iterations))

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "AugmentConfig":
        d = dict(d)
        if d.get("camera") is not None:
            d["camera"] = tuple(d["camera"])
        return cls(**d)


class Augmenter:
    """The pseudo-GT pool of one training run: rebuilt on schedule, drawn from, saved with checkpoints."""

    def __init__(self, cfg: AugmentConfig, subject: Subject, frames: FrameSet, iterations: int, seed: int) -> None:
        from trioman.toolkit.train.pseudo_models import load_pseudo_examiner, load_pseudo_refiner

        self.cfg, self.subject, self.frames = cfg, subject, frames
        self.start = cfg.start_step(iterations)
        self.gen_cfg = cfg.generator()
        self.refiner = load_pseudo_refiner(cfg.refiner) if cfg.mode != "coarse" else None
        if self.refiner is not None:
            self.refiner.check_size(frames.height, frames.width, "--refiner")
        use_examiner = cfg.mode == "examined" and (cfg.candidates > 1 or cfg.threshold is not None)
        self.examiner = load_pseudo_examiner(cfg.examiner) if use_examiner else None
        self.rng = np.random.default_rng([int(seed), 0xA06])  # apart from the real-frame draws
        self.background = subject.background.astype(np.float32)
        self.pool: dict[str, torch.Tensor] | None = None
        self.stats: dict[str, Any] = {"rebuilds": 0, "pseudo_steps": 0, "candidates": 0, "kept": 0, "dropped": 0,
                                      "score_sum": 0.0, "scored": 0, "seconds": dict.fromkeys(STAGES, 0.0)}

    # ---- schedule

    def due(self, step: int) -> bool:
        """Rebuild the pool before training step ``step`` (0-based)?"""
        return step >= self.start and (step - self.start) % self.cfg.refresh == 0

    def use_pseudo(self, step: int) -> bool:
        """Whether step ``step`` trains on a pool frame (draws from this module's generator after the warm-up)."""
        if step < self.start:
            return False
        take = bool(self.rng.random() < self.cfg.share)
        return take and self.pool is not None and len(self.pool["images"]) > 0

    def draw(self) -> dict[str, Any]:
        """A pool frame: images/masks/poses/trans/K/viewmat of one entry and its loss weight."""
        j = int(self.rng.integers(len(self.pool["images"])))
        self.stats["pseudo_steps"] += 1
        return {**{k: v[j] for k, v in self.pool.items()}, "weight": self.cfg.weight}

    # ---- building

    @torch.no_grad()
    def rebuild(self, model: GaussianAvatar) -> None:
        entries = []
        for _ in range(self.cfg.pool):
            entry = self._make(model, int(self.rng.integers(len(self.frames))))
            if entry is not None:
                entries.append(entry)
        H, W = self.frames.height, self.frames.width
        empty = {"images": (0, H, W, 3), "masks": (0, H, W), "poses": (0, *self.frames.poses.shape[1:]),
                 "trans": (0, 3), "K": (0, 3, 3), "viewmat": (0, 4, 4)}
        self.pool = {k: torch.stack([e[k] for e in entries]) if entries else torch.zeros(empty[k]) for k in _POOL_KEYS}
        self.stats["rebuilds"] += 1

    def _make(self, model: GaussianAvatar, i: int) -> dict[str, torch.Tensor] | None:
        t, sec = time.perf_counter(), self.stats["seconds"]
        f, bg = self.frames, self.background
        W, H = f.width, f.height
        K, real_mask = f.K[i].numpy().astype(np.float64), f.mask(i).numpy()
        real = f.image(i).numpy() + (1.0 - real_mask)[..., None] * bg  # I^T over the subject's background
        cands = sample(self.subject.body.skeleton, f.poses[i].numpy(), f.trans[i].numpy(), f.viewmat[i].numpy(),
                       self.rng, self.cfg.candidates, self.gen_cfg)
        t = _tick(sec, "generate", t)
        renders = [render_candidate(model, c, f.K[i], W, H, bg) for c in cands]
        coarse_b, alpha_b = np.stack([r for r, _ in renders]), np.stack([a for _, a in renders])
        t = _tick(sec, "render", t)
        self.stats["candidates"] += len(cands)
        images = coarse_b
        if self.refiner is not None:
            normal = None
            if self.refiner.conditions == "tex+geo":
                normal = np.stack([body_normal_map(self.subject.body, c.pose, c.trans, c.viewmat, K, W, H).rgb
                                   for c in cands]).astype(np.float32)
            t = _tick(sec, "normal", t)
            reference = None if self.refiner.conditions == "none" else np.broadcast_to(real, coarse_b.shape).astype(np.float32)
            images = np.asarray(self.refiner.refine(coarse_b, reference=reference, normal=normal), dtype=np.float32)
            if self.cfg.detail_sigma > 0:
                images = keep_detail(coarse_b, images, self.cfg.detail_sigma)
            t = _tick(sec, "refine", t)
        k = 0
        if self.examiner is not None:
            scores = np.asarray(self.examiner.score(images, real.astype(np.float32)), dtype=np.float64)
            k = int(np.argmax(scores))
            self.stats["score_sum"] += float(scores[k])
            self.stats["scored"] += 1
            t = _tick(sec, "examine", t)
            if self.cfg.threshold is not None and scores[k] < self.cfg.threshold:
                self.stats["dropped"] += 1
                return None
        self.stats["kept"] += 1
        a = alpha_b[k]
        premult = np.clip(images[k] - (1.0 - a)[..., None] * bg, 0.0, 1.0)  # colour on black, as FrameSet holds it
        c = cands[k]
        return {"images": torch.from_numpy(premult.astype(np.float32)), "masks": torch.from_numpy(a.astype(np.float32)),
                "poses": torch.from_numpy(c.pose.astype(np.float32)), "trans": torch.from_numpy(c.trans.astype(np.float32)),
                "K": f.K[i].clone(), "viewmat": torch.from_numpy(c.viewmat.astype(np.float32))}

    # ---- checkpoints

    def state_dict(self) -> dict[str, Any]:
        return {"rng": json.dumps(self.rng.bit_generator.state), "stats": json.dumps(self.stats),
                "pool": None if self.pool is None else dict(self.pool)}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.rng.bit_generator.state = json.loads(state["rng"])
        self.stats = json.loads(state["stats"])
        self.pool = None if state["pool"] is None else dict(state["pool"])

    def summary(self, steps: int) -> dict[str, Any]:
        """Counts, mean kept score and seconds per stage (total and per training step)."""
        s = self.stats
        return {"mode": self.cfg.mode, "config": dataclasses.asdict(self.cfg), "start_step": self.start,
                **{k: s[k] for k in ("rebuilds", "pseudo_steps", "candidates", "kept", "dropped")},
                "mean_kept_score": s["score_sum"] / s["scored"] if s["scored"] else None,
                "seconds": s["seconds"], "ms_per_step": {k: 1e3 * v / max(steps, 1) for k, v in s["seconds"].items()}}


@torch.no_grad()
def render_candidate(model: GaussianAvatar, c: Any, K: torch.Tensor, width: int, height: int,
                     background: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The avatar (refined set) at a Generator candidate's pose and camera over ``background``:
    -> (rgb [H, W, 3], alpha [H, W]) float32 in [0, 1]. K: [3, 3]."""
    g = model(torch.from_numpy(c.pose.astype(np.float32)), torch.from_numpy(c.trans.astype(np.float32))).refined
    r = rasterize(g.means, g.quats, g.scales, g.opacities, g.colors, torch.from_numpy(c.viewmat.astype(np.float32)),
                  K, width, height, background=torch.from_numpy(background))
    return r.rgb.clamp(0, 1).numpy(), r.alpha.clamp(0, 1).numpy()


def _tick(seconds: dict[str, float], stage: str, t: float) -> float:
    now = time.perf_counter()
    seconds[stage] += now - t
    return now
