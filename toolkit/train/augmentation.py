"""Online augmentation (paper 3.2.3-3.2.7): pseudo-GT frames made during the avatar's own optimisation.

After a warm-up of ``start`` x iterations, every ``refresh`` steps the pool of pseudo-GT frames is
rebuilt: each of its ``pool`` entries is a random training frame's Generator candidates, rendered by the
avatar as it is at the rebuild (no grad) and turned into pseudo-GT by the shared augmentation step
(``trioman.runtime.pseudo_gt.make_pseudo_frames``, the one ``trioman augment`` runs), which gives the
frame its image, mask and per-pixel loss weights. Each step after the warm-up trains on a pool frame
with probability ``share``, with loss weight ``weight``. An entry is made when a step first draws it,
from a copy of the avatar taken at the rebuild, so entries no step draws cost nothing and the frames are
those an eager rebuild would make. The pool, that copy and this module's random state live in the
checkpoints, so a resumed run equals an uninterrupted one.
"""

from __future__ import annotations

import dataclasses
import json
import time
from typing import Any

import numpy as np
import torch

from trioman.runtime.aligned import AlignConfig, Aligner, SourceViews
from trioman.runtime.formats import Subject
from trioman.runtime.generator import CameraDelta, Candidate, sample
from trioman.runtime.pseudo_gt import STAGES, Source, make_pseudo_frames, needs_aligner
from trioman.toolkit.avatar.model import GaussianAvatar, PoseFree
from trioman.toolkit.render import rasterize
from trioman.toolkit.train.augment_config import AugmentConfig
from trioman.toolkit.train.data import FrameSet

class Augmenter:
    """The pseudo-GT pool of one training run: rebuilt on schedule, drawn from, saved with checkpoints."""

    def __init__(self, cfg: AugmentConfig, subject: Subject, frames: FrameSet, iterations: int, seed: int) -> None:
        from trioman.toolkit.train.augment_models import load_pseudo_examiner, load_pseudo_refiner

        self.cfg, self.subject, self.frames = cfg, subject, frames
        self.start = cfg.start_step(iterations)
        self.gen_cfg = cfg.generator()
        self.pseudo_cfg = cfg.pseudo()
        self.refiner = load_pseudo_refiner(cfg.refiner) if cfg.refiner else None
        if self.refiner is not None:
            self.refiner.check_size(frames.height, frames.width)
        use_examiner = cfg.mode == "examined" and (cfg.candidates > 1 or cfg.threshold is not None)
        self.examiner = load_pseudo_examiner(cfg.examiner) if use_examiner else None
        self.rng = _own_rng(seed)
        self.background = subject.background.astype(np.float32)
        self.aligner = None
        if needs_aligner(self.pseudo_cfg, None if self.refiner is None else self.refiner.conditions):
            views = SourceViews(lambda p: frames.image(p).numpy(), lambda p: frames.mask(p).numpy(), frames.poses.numpy(),
                                frames.trans.numpy(), frames.viewmat.numpy(), frames.K.numpy(), frames.width, frames.height)
            self.aligner = Aligner(subject.body, views, AlignConfig(sources=cfg.align_sources, texture=cfg.align_texture))
        self.truth = None
        if self.pseudo_cfg.from_truth:
            from trioman.toolkit.synth.subject import TruthRenderer

            self.truth = TruthRenderer(subject)
        self.entries: list[dict[str, Any]] | None = None  # the pool: made frames and pending draws (_pending)
        self.snapshot: GaussianAvatar | None = None  # the avatar at the last rebuild: renders the pending entries
        self.pose_free: PoseFree | None = None  # the snapshot's pose-independent part, made with the first entry
        self.stats: dict[str, Any] = _fresh_stats()

    # ---- schedule

    def due(self, step: int) -> bool:
        """Rebuild the pool before training step ``step`` (0-based)?"""
        return step >= self.start and (step - self.start) % self.cfg.refresh == 0

    def use_pseudo(self, step: int) -> bool:
        """Whether step ``step`` trains on a pool frame (draws from this module's generator after the warm-up)."""
        if step < self.start:
            return False
        take = bool(self.rng.random() < self.cfg.share)
        return take and bool(self.entries)

    def draw(self) -> dict[str, Any] | None:
        """A pool frame: images/masks/pixel_weights/poses/trans/K/viewmat of one entry and its loss weight, made
        now if no step drew it before. An entry the Examiner drops leaves the pool and another is drawn (so the
        draw is uniform over the kept entries); None when every entry was dropped."""
        while self.entries:
            j = int(self.rng.integers(len(self.entries)))
            if "images" not in self.entries[j]:
                made = self._make(self.entries[j]["source"], self.entries[j]["candidates"])
                if made is None:
                    del self.entries[j]
                    continue
                self.entries[j] = made
            self.stats["pseudo_steps"] += 1
            return {**self.entries[j], "weight": self.cfg.weight}
        return None

    # ---- building

    @torch.no_grad()
    def rebuild(self, model: GaussianAvatar) -> None:
        """A new pool: every entry's source frame and Generator candidates are drawn now, in the order an eager
        rebuild draws them, and rendered later by a copy of ``model`` as it is now."""
        if self.snapshot is None:
            self.snapshot = GaussianAvatar(self.subject.body, model.cfg).requires_grad_(False)
        self.snapshot.load_state_dict(model.state_dict())
        self.pose_free = None
        t = time.perf_counter()
        self.entries = []
        f = self.frames
        for _ in range(self.cfg.pool):
            i = int(self.rng.integers(len(f)))
            cands = sample(self.subject.body.skeleton, f.poses[i].numpy(), f.trans[i].numpy(), f.viewmat[i].numpy(),
                           self.rng, self.cfg.candidates, self.gen_cfg)
            self.entries.append({"source": i, "candidates": cands})
        self.stats["seconds"]["generate"] += time.perf_counter() - t
        self.stats["rebuilds"] += 1
        self.stats["entries"] += self.cfg.pool

    @torch.no_grad()
    def _make(self, i: int, cands: list[Candidate]) -> dict[str, torch.Tensor] | None:
        """The pool frame of source frame ``i``'s candidates, rendered by the snapshot; None when dropped."""
        sec = self.stats["seconds"]
        if self.pose_free is None:
            t = time.perf_counter()
            self.pose_free = self.snapshot.pose_free()
            sec["render"] += time.perf_counter() - t
        f, bg = self.frames, self.background
        W, H = f.width, f.height
        real_mask = f.mask(i).numpy()
        real = f.image(i).numpy() + (1.0 - real_mask)[..., None] * bg  # I^T over the subject's background
        source = Source(i, real.astype(np.float32), f.K[i].numpy(), bg)
        truth = None if self.truth is None else (lambda c, K: self.truth.at_draw(int(f.indices[i]), c, K))
        made = make_pseudo_frames(cands, source, lambda c: render_candidate(self.snapshot, c, f.K[i], W, H, bg, self.pose_free),
                                  self.pseudo_cfg, body=self.subject.body, aligner=self.aligner, refiner=self.refiner,
                                  examiner=self.examiner, truth=truth, seconds=sec)
        self.stats["candidates"] += len(cands)
        self.stats["coverage_sum"] += float(sum(made.coverage))
        self.stats["aligned"] += len(made.coverage)
        if made.scores is not None:
            self.stats["score_sum"] += made.scores[made.chosen]
            self.stats["scored"] += 1
        if not made.kept:
            self.stats["dropped"] += 1
            return None
        self.stats["kept"] += 1
        k = made.kept[0]
        m = made.masks[k]
        premult = np.clip(made.images[k] - (1.0 - m)[..., None] * bg, 0.0, 1.0)  # colour on black, as FrameSet holds it
        c = cands[k]
        return {"images": torch.from_numpy(premult.astype(np.float32)), "masks": torch.from_numpy(m),
                "pixel_weights": torch.from_numpy(made.weights[k]),
                "poses": torch.from_numpy(c.pose.astype(np.float32)), "trans": torch.from_numpy(c.trans.astype(np.float32)),
                "K": f.K[i].clone(), "viewmat": torch.from_numpy(c.viewmat.astype(np.float32))}

    # ---- checkpoints

    @staticmethod
    def initial_state(seed: int) -> dict[str, Any]:
        """``state_dict()`` of a run's Augmenter before its first rebuild (no models loaded)."""
        return {"rng": json.dumps(_own_rng(seed).bit_generator.state), "stats": json.dumps(_fresh_stats()),
                "entries": None, "snapshot": None}

    def state_dict(self) -> dict[str, Any]:
        pending = self.entries is not None and any("images" not in e for e in self.entries)
        entries = None if self.entries is None else [
            e if "images" in e else {"source": e["source"], "candidates": _candidates_json(e["candidates"])}
            for e in self.entries]
        return {"rng": json.dumps(self.rng.bit_generator.state), "stats": json.dumps(self.stats), "entries": entries,
                "snapshot": self.snapshot.state_dict() if pending else None}

    def load_state_dict(self, state: dict[str, Any], model: GaussianAvatar) -> None:
        """``model``: the avatar being trained (its config builds the snapshot that renders pending entries)."""
        self.rng.bit_generator.state = json.loads(state["rng"])
        self.stats = json.loads(state["stats"])
        if "entries" in state:
            self.entries = None if state["entries"] is None else [
                e if "images" in e else {"source": int(e["source"]), "candidates": _candidates_from_json(e["candidates"])}
                for e in state["entries"]]
        else:  # a checkpoint from before pending entries: every pool frame was made at its rebuild
            pool = state["pool"]
            self.entries = None if pool is None else [{k: v[j] for k, v in pool.items()} for j in range(len(pool["images"]))]
        if state.get("snapshot") is not None:
            self.snapshot = GaussianAvatar(self.subject.body, model.cfg).requires_grad_(False)
            self.snapshot.load_state_dict(state["snapshot"])
            self.pose_free = None
        for e in self.entries or []:
            if "images" in e and "pixel_weights" not in e:  # a checkpoint from before per-pixel weights
                e["pixel_weights"] = torch.ones_like(e["masks"])
        self.stats.setdefault("coverage_sum", 0.0)
        self.stats.setdefault("aligned", 0)
        self.stats.setdefault("entries", self.stats["rebuilds"] * self.cfg.pool)
        for stage in STAGES:
            self.stats["seconds"].setdefault(stage, 0.0)

    def summary(self, steps: int) -> dict[str, Any]:
        """Counts (pool entries drawn at the rebuilds; candidates rendered, kept and dropped for the entries
        steps drew), mean kept score and seconds per stage (total and per training step)."""
        s = self.stats
        return {"mode": self.cfg.mode, "config": dataclasses.asdict(self.cfg), "start_step": self.start,
                **{k: s[k] for k in ("rebuilds", "entries", "pseudo_steps", "candidates", "kept", "dropped")},
                "mean_kept_score": s["score_sum"] / s["scored"] if s["scored"] else None,
                "mean_body_coverage": s["coverage_sum"] / s["aligned"] if s["aligned"] else None,
                "seconds": s["seconds"], "ms_per_step": {k: 1e3 * v / max(steps, 1) for k, v in s["seconds"].items()}}


def _own_rng(seed: int) -> np.random.Generator:
    """The augmentation's random state, apart from the real-frame draws."""
    return np.random.default_rng([int(seed), 0xA06])


def _fresh_stats() -> dict[str, Any]:
    return {"rebuilds": 0, "entries": 0, "pseudo_steps": 0, "candidates": 0, "kept": 0, "dropped": 0,
            "score_sum": 0.0, "scored": 0, "coverage_sum": 0.0, "aligned": 0, "seconds": dict.fromkeys(STAGES, 0.0)}


def _candidates_json(cands: list[Candidate]) -> str:
    """Candidates as JSON (floats round-trip exactly): a checkpoint holds data, never pickled objects."""
    return json.dumps([{"pose": c.pose.tolist(), "trans": c.trans.tolist(), "viewmat": c.viewmat.tolist(),
                        "delta_pose": c.delta_pose.tolist(), "camera": dataclasses.asdict(c.camera),
                        "center": c.center.tolist()} for c in cands])


def _candidates_from_json(text: str) -> list[Candidate]:
    return [Candidate(np.array(d["pose"]), np.array(d["trans"]), np.array(d["viewmat"]), np.array(d["delta_pose"]),
                      CameraDelta(**d["camera"]), np.array(d["center"])) for d in json.loads(text)]


@torch.no_grad()
def render_candidate(model: GaussianAvatar, c: Any, K: torch.Tensor, width: int, height: int,
                     background: np.ndarray, pose_free: PoseFree | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The avatar (refined set) at a Generator candidate's pose and camera over ``background``:
    -> (rgb [H, W, 3], alpha [H, W]) float32 in [0, 1]. K: [3, 3]; pose_free: ``model.pose_free()``, for many
    candidates."""
    g = model(torch.from_numpy(c.pose.astype(np.float32)), torch.from_numpy(c.trans.astype(np.float32)), pose_free).refined
    r = rasterize(g.means, g.quats, g.scales, g.opacities, g.colors, torch.from_numpy(c.viewmat.astype(np.float32)),
                  K, width, height, background=torch.from_numpy(background))
    return r.rgb.clamp(0, 1).numpy(), r.alpha.clamp(0, 1).numpy()

