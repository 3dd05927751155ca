"""One source frame of an augment run: the Generator's draws, the shared augmentation step
(runtime/pseudo_gt.py), the kept frames' files and the frame's record."""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from trioman.runtime.aligned import AlignConfig, Aligner, SourceViews
from trioman.runtime.augment.layout import AUGMENT_VERSION, STAGES, dump, record_path
from trioman.runtime.formats.avatar import sha256_file
from trioman.runtime.formats.subject import IMAGES_DIR, MASKS_DIR, WEIGHTS_DIR
from trioman.runtime.generator import GROUPS, GeneratorConfig, sample
from trioman.runtime.image_io import write_png
from trioman.runtime.outputs import atomic_write_text
from trioman.runtime.pseudo_gt import PseudoConfig, Source, make_pseudo_frames, needs_aligner
from trioman.runtime.render import rasterize


def frame_seed(seed: int, index: int) -> int:
    """The Generator seed of source frame ``index`` (its index in the subject) for the run seed ``seed``."""
    return int(np.random.SeedSequence([int(seed), int(index)]).generate_state(1, np.uint64)[0])


@dataclass(frozen=True)
class Step:
    """What the augmentation step of every source frame shares."""

    avatar: Any
    refiner: Any
    examiner: Any
    aligner: Aligner | None
    pseudo: PseudoConfig
    positions: dict[int, int]  # subject frame index -> position in the aligner's views
    seed: int
    per_frame: int
    generator: GeneratorConfig

    @property
    def weighted(self) -> bool:
        """Whether the frames carry per-pixel loss weights (kind aligned: only known pixels are supervised)."""
        return self.pseudo.kind == "aligned"


def make_aligner(subj: Any, indices: np.ndarray, pseudo: PseudoConfig, refiner: Any, texture: int = 0) -> Aligner | None:
    """The aligned reference over the subject's frames ``indices`` (when the pseudo-GT needs it); ``texture``:
    ``AlignConfig.texture``."""
    if not needs_aligner(pseudo, None if refiner is None else refiner.conditions):
        return None
    return Aligner(subj.body, SourceViews.of_subject(subj, indices), AlignConfig(texture=texture))


def _group_norms(delta: np.ndarray, groups: np.ndarray) -> dict[str, float]:
    """Frobenius norm of the pose change per joint group (radians)."""
    return {g: float(np.linalg.norm(delta[groups == g])) for g in GROUPS if np.any(groups == g)}


def _write_frame_png(path: Path, img: np.ndarray) -> str:
    """Write a frame file (atomic) -> the sha256 of its bytes as written, kept in the record (check_record
    verifies it)."""
    write_png(path, img)
    return sha256_file(path)


def augment_frame(subj: Any, i: int, step: Step, out: Path, groups: np.ndarray) -> dict:
    """Source frame ``i`` of ``subj`` into ``out``: the kept frames' files, then its record (-> the record)."""
    t = dict.fromkeys(STAGES, 0.0)
    H, W = subj.height, subj.width
    K, bg = np.array(subj.K[i], dtype=np.float64), subj.background.astype(np.float32)
    name = str(subj.frame_names[i])

    t0 = time.perf_counter()
    fseed = frame_seed(step.seed, i)
    cands = sample(subj.body.skeleton, subj.poses[i], subj.trans[i], subj.viewmat[i], fseed, step.per_frame, step.generator)
    real = subj.image(i)
    t["generate"] = time.perf_counter() - t0

    def render(c: Any) -> tuple[np.ndarray, np.ndarray]:
        r = rasterize(*step.avatar.gaussians(c.pose, c.trans), c.viewmat, K, W, H, background=bg)
        return np.clip(r.rgb, 0.0, 1.0), np.clip(r.alpha, 0.0, 1.0)

    made = make_pseudo_frames(cands, Source(step.positions[int(i)], real, K, bg), render, step.pseudo, body=subj.body,
                              aligner=step.aligner, refiner=step.refiner, examiner=step.examiner, seconds=t)
    t5 = time.perf_counter()
    out_frames, candidates = [], []
    for k, c in enumerate(cands):
        fname = f"{name}_c{k}"
        if k in made.kept:  # the image shows the background where the mask is 0 (subject format)
            files = {IMAGES_DIR: made.images[k], MASKS_DIR: made.masks[k],
                     **({WEIGHTS_DIR: made.weights[k]} if step.weighted else {})}
            digests = {sub: _write_frame_png(out / sub / f"{fname}.png", img) for sub, img in files.items()}
            out_frames.append({"name": fname, "candidate": k, "pose": c.pose.tolist(), "trans": c.trans.tolist(),
                               "viewmat": c.viewmat.tolist(), "K": K.tolist(), **({"weights": True} if step.weighted else {}),
                               "sha256": digests})
        if made.scores is None:
            status = "kept"
        elif k != made.chosen:
            status = "not_chosen"
        else:
            status = "accepted" if made.kept else "rejected"
        candidates.append({
            "candidate": k, "status": status, "score": None if made.scores is None else made.scores[k],
            "frame": fname if k in made.kept else None,
            "body_coverage": made.coverage[k] if made.coverage else None,
            "pose_delta_norm": _group_norms(c.delta_pose, groups),
            "camera": {"azimuth": c.camera.azimuth, "elevation": c.camera.elevation,
                       "log_distance": c.camera.log_distance},
        })
    rec = {
        "version": AUGMENT_VERSION,
        "source": {"index": int(i), "name": name, "sequence": str(subj.sequence[i])},
        "seed": fseed,
        "chosen": made.chosen,
        "kept": bool(made.kept),
        "candidates": candidates,
        "frames": out_frames,
        "seconds": t,
    }
    t["write"] = time.perf_counter() - t5  # images and masks; the record's own write is not counted
    atomic_write_text(record_path(out, name), dump(rec))
    return rec
