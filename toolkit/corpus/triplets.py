"""Data construction for the Refiner and Examiner (paper 3.2.4): per subject frame T, the GT I^T, the
baseline avatar's coarse render I_c^T at the same pose and camera, the body normal map I_g^T and the
aligned reference, in one triplet file; ``TripletSet`` samples training tuples with a GT I^{T+k} from the
same sequence (0 < |k| <= K).

The file: docs/formats.md, "Triplets"; the aligned reference's sources: docs/augmentation.md, "Refiner
conditions".
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np

from trioman.runtime.formats.common import FormatError, load_npz
from trioman.runtime.outputs import atomic_path, check_not_input
from trioman.runtime.normal_map import body_normal_map
from trioman.runtime.rotations import axis_angle_to_matrix
from trioman.toolkit.corpus.triplets_config import TripletsOptions

TRIPLETS_VERSION = 2
_ARRAYS = ("meta", "gt", "mask", "coarse", "normal", "frame", "split", "sequence", "view_yaw")
_ALIGNED_ARRAYS = ("aligned", "valid", "aligned_from")  # version >= 2
ALIGN_K = 4  # |k| of the own source frame of a triplet's aligned reference
_FORWARD = np.array([0.0, -1.0, 0.0])  # the rest body faces -y (runtime/cameras.py)


def view_yaw(root_pose: np.ndarray, viewmat: np.ndarray) -> np.ndarray:
    """Azimuth of the body's facing direction in camera coordinates. [N, 3], [N, 4, 4] -> [N] radians,
    0 when the body faces the camera, +-pi when it shows its back."""
    facing = axis_angle_to_matrix(root_pose) @ _FORWARD  # world
    cam = np.einsum("nab,nb->na", viewmat[:, :3, :3], facing)
    return np.arctan2(cam[:, 0], -cam[:, 2]).astype(np.float32)


def _u8(img: np.ndarray) -> np.ndarray:
    return np.clip(np.rint(img * 255.0), 0, 255).astype(np.uint8)


def triplets_version(path: str | Path) -> int:
    """The format version in a triplet file's meta (reads nothing else); FormatError for a file that is not one."""
    try:
        with np.load(path, allow_pickle=False) as z:
            return int(json.loads(str(z["meta"]))["version"])
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise FormatError(f"{path}: meta: not a readable triplet file ({e})") from None


def _own_source(split: np.ndarray, sequence: np.ndarray, i: int, rng: np.random.Generator) -> int | None:
    """A training frame of frame i's sequence at 0 < |k| <= ALIGN_K (drawn), None when there is none."""
    lo, hi = max(0, i - ALIGN_K), min(len(split), i + ALIGN_K + 1)
    cand = [j for j in range(lo, hi) if j != i and split[j] == "train" and sequence[j] == sequence[i]]
    return int(rng.choice(cand)) if cand else None


def aligned_references(subject, coarse: np.ndarray, seed: int = 0,
                       progress: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every frame T's aligned reference from the subject's other training frames (docs/augmentation.md,
    "Refiner conditions").
    coarse [N, H, W, 3] uint8 (the render flow re-aligns to) -> (aligned uint8 [N, H, W, 3], valid uint8
    [N, H, W], aligned_from int32 [N])."""
    from tqdm import tqdm

    from trioman.runtime.aligned import Aligner, SourceViews

    split, sequence = np.asarray(subject.split), np.asarray(subject.sequence)
    train = np.nonzero(split == "train")[0]
    if len(train) < 2:
        raise ValueError(f"{subject.root}: split: {len(train)} training frame(s); aligned references need at least 2")
    pos = {int(f): p for p, f in enumerate(train)}
    aligner = Aligner(subject.body, SourceViews.of_subject(subject, train))
    n, H, W = len(coarse), subject.height, subject.width
    aligned, valid = np.zeros((n, H, W, 3), np.uint8), np.zeros((n, H, W), np.uint8)
    source = np.empty(n, np.int32)
    rng = np.random.default_rng(seed)
    for i in tqdm(range(n), desc="aligned references", unit="frame", disable=None if progress else True):
        pose, trans, viewmat = (np.asarray(a[i]) for a in (subject.poses, subject.trans, subject.viewmat))
        exclude = [pos[i]] if i in pos else []
        own = _own_source(split, sequence, i, rng)
        if own is None:  # no training frame nearby in the sequence: the one seeing the body most alike
            own = int(train[aligner.sources_for(-1, pose, trans, viewmat, exclude)[1]])
        a = aligner.align(pos[own], pose, trans, viewmat, np.asarray(subject.K[i]), coarse[i] / np.float32(255.0), exclude)
        aligned[i], valid[i], source[i] = _u8(a.rgb), a.valid.astype(np.uint8) * 255, own
    return aligned, valid, source


def _check_out(out: str | Path, run: str | Path, subject) -> None:
    """ValueError (``out: ...``) when the triplets file would land in the run, its subject or another output."""
    try:
        check_not_input(out, [run, subject.root])
    except ValueError as err:
        raise ValueError(f"out: {err}") from None


def build_triplets(run: str | Path, out: str | Path, progress: bool = True) -> Path:
    """Render coarse frames and normal maps for every frame of the run's subject into ``out`` (.npz)."""
    import torch
    from tqdm import tqdm

    from trioman.toolkit.evaluate import load_run, render_frame

    model, subject, _, step = load_run(run)
    _check_out(out, run, subject)
    bg = subject.background
    n, H, W = subject.num_frames, subject.height, subject.width
    arrays = {k: np.empty((n, H, W, 3), np.uint8) for k in ("gt", "coarse", "normal")}
    arrays["mask"] = np.empty((n, H, W), np.uint8)
    with torch.no_grad():
        pose_free = model.pose_free()
    for i in tqdm(range(n), desc="triplets", unit="frame", disable=None if progress else True):
        arrays["gt"][i] = _u8(subject.image(i))
        arrays["mask"][i] = _u8(subject.mask(i))
        arrays["coarse"][i] = _u8(render_frame(model, subject, i, torch.from_numpy(bg), pose_free=pose_free))
        nm = body_normal_map(subject.body, subject.poses[i], subject.trans[i], subject.viewmat[i], subject.K[i], W, H)
        arrays["normal"][i] = _u8(nm.rgb)
    meta = {"version": TRIPLETS_VERSION, "subject": str(subject.root), "run": str(run), "step": step,
            "width": W, "height": H, "background": bg.tolist()}
    arrays.update(
        meta=np.array(json.dumps(meta)), frame=np.arange(n, dtype=np.int32),
        split=np.array(subject.split, dtype=np.str_), sequence=np.array(subject.sequence, dtype=np.str_),
        view_yaw=view_yaw(np.array(subject.poses[:, 0]), np.array(subject.viewmat)),
    )
    arrays["aligned"], arrays["valid"], arrays["aligned_from"] = aligned_references(subject, arrays["coarse"], progress=progress)
    out = Path(out)
    with atomic_path(out, suffix=".npz") as tmp:
        with open(tmp, "wb") as f:
            np.savez(f, **arrays)
    return out


def build_draw_triplets(run: str | Path, out: str | Path, draws: int, seed: int = TripletsOptions.seed,
                        progress: bool = True) -> Path:
    """Triplets at Generator draws of a synthetic subject's training frames (``draws`` per frame): what a Refiner
    meets during augmentation. ``gt`` is the truth at the draw (the subject's own renderer, over its background),
    ``coarse`` the avatar's render there, ``aligned`` the draw's aligned reference from its own source frame and
    the nearest-direction training frames (as the shared augmentation step builds it), ``normal`` the body
    normal map; every row is split "train" and ``frame`` / ``aligned_from`` name the source frame. Same format
    (version 2) as ``build_triplets``."""
    import torch
    from tqdm import tqdm

    from trioman.runtime.aligned import Aligner, SourceViews
    from trioman.runtime.generator import sample
    from trioman.toolkit.evaluate import load_run
    from trioman.toolkit.synth.subject import TruthRenderer
    from trioman.toolkit.train.augmentation import AugmentConfig, render_candidate

    model, subject, _, step = load_run(run)
    _check_out(out, run, subject)
    truth = TruthRenderer(subject)
    bg, H, W = subject.background.astype(np.float32), subject.height, subject.width
    train = subject.indices("train")
    aligner, gen = Aligner(subject.body, SourceViews.of_subject(subject, train)), AugmentConfig().generator()
    rng = np.random.default_rng(seed)
    n = len(train) * draws
    arrays = {k: np.empty((n, H, W, 3), np.uint8) for k in ("gt", "coarse", "normal", "aligned")}
    arrays.update(mask=np.empty((n, H, W), np.uint8), valid=np.empty((n, H, W), np.uint8))
    frame, yaw_pose, yaw_view = np.empty(n, np.int32), np.empty((n, 3)), np.empty((n, 4, 4))
    with torch.no_grad():
        pose_free = model.pose_free()
        for r in tqdm(range(n), desc="draw triplets", unit="draw", disable=None if progress else True):
            p = r // draws
            i = int(train[p])
            c = sample(subject.body.skeleton, np.asarray(subject.poses[i]), np.asarray(subject.trans[i]),
                       np.asarray(subject.viewmat[i]), rng, 1, gen)[0]
            K = np.asarray(subject.K[i], np.float64)
            coarse, _ = render_candidate(model, c, torch.from_numpy(K.astype(np.float32)), W, H, bg, pose_free)
            rgb, mask = truth.at_draw(i, c, K)
            a = aligner.align(p, c.pose, c.trans, c.viewmat, K, coarse)
            arrays["gt"][r], arrays["mask"][r] = _u8(rgb + (1.0 - mask)[..., None] * bg), _u8(mask)
            arrays["coarse"][r], arrays["aligned"][r], arrays["valid"][r] = _u8(coarse), _u8(a.rgb), a.valid.astype(np.uint8) * 255
            arrays["normal"][r] = _u8(body_normal_map(subject.body, c.pose, c.trans, c.viewmat, K, W, H).rgb)
            frame[r], yaw_pose[r], yaw_view[r] = i, c.pose[0], c.viewmat
    meta = {"version": TRIPLETS_VERSION, "subject": str(subject.root), "run": str(run), "step": step, "width": W,
            "height": H, "background": bg.tolist(), "draws": draws, "seed": seed}
    arrays.update(meta=np.array(json.dumps(meta)), frame=frame, aligned_from=frame.copy(),
                  split=np.full(n, "train"), sequence=np.asarray(subject.sequence)[frame].astype(np.str_),
                  view_yaw=view_yaw(yaw_pose, yaw_view))
    out = Path(out)
    with atomic_path(out, suffix=".npz") as tmp:
        with open(tmp, "wb") as f:
            np.savez(f, **arrays)
    return out


class Tuples(NamedTuple):
    """Float32 NHWC images in [0, 1]: the data of one batch."""

    gt: np.ndarray  # [B, H, W, 3] I^T
    coarse: np.ndarray  # [B, H, W, 3] I_c^T
    normal: np.ndarray  # [B, H, W, 3] I_g^T
    reference: np.ndarray  # [B, H, W, 3] I^{T+k} (or the nearest-view training frame)
    mask: np.ndarray  # [B, H, W] mask of I^T
    aligned: np.ndarray | None = None  # [B, H, W, 3] T's aligned reference, the coarse render where nothing was carried


@dataclass(eq=False)
class TripletSet:
    """Triplets of one or more subjects, in memory (uint8)."""

    gt: np.ndarray
    mask: np.ndarray
    coarse: np.ndarray
    normal: np.ndarray
    split: np.ndarray
    group: np.ndarray  # [N] "<file index>/<sequence>": frames that may pair as T and T+k
    subject: np.ndarray  # [N] file index
    view_yaw: np.ndarray
    aligned: np.ndarray | None = None  # [N, H, W, 3] uint8, the aligned reference filled with ``coarse``; None
    # when a file lacks it (version 1)

    @classmethod
    def load(cls, paths: list[str | Path]) -> "TripletSet":
        parts = []
        for s, p in enumerate(paths):
            a = load_npz(Path(p))
            for key in _ARRAYS:
                if key not in a:
                    raise FormatError(f"{p}: {key}: missing array (not a triplet file?)")
            n = len(a["frame"])
            for key in ("gt", "coarse", "normal", "mask", "split", "sequence", "view_yaw"):
                if len(a[key]) != n:
                    raise FormatError(f"{p}: {key}: {len(a[key])} entries for {n} frames")
            if all(key in a for key in _ALIGNED_ARRAYS):
                if a["aligned"].shape != a["coarse"].shape or a["valid"].shape != a["mask"].shape:
                    raise FormatError(f"{p}: aligned/valid: shapes {a['aligned'].shape}/{a['valid'].shape} differ from "
                                      f"coarse/mask {a['coarse'].shape}/{a['mask'].shape}")
                a["aligned"] = np.where(a["valid"][..., None] > 127, a["aligned"], a["coarse"])
            a["group"] = np.char.add(f"{s}/", a["sequence"])
            a["subject"] = np.full(n, s, np.int32)
            parts.append(a)
        if not parts:
            raise ValueError("paths: no triplet files given")
        shapes = {x["gt"].shape[1:] for x in parts}
        if len(shapes) != 1:
            raise FormatError(f"triplets: image sizes differ between files: {sorted(shapes)}")
        cat = {k: np.concatenate([x[k] for x in parts]) for k in
               ("gt", "mask", "coarse", "normal", "split", "group", "subject", "view_yaw")}
        if all("aligned" in x for x in parts):
            cat["aligned"] = np.concatenate([x["aligned"] for x in parts])
        return cls(**cat)

    def __len__(self) -> int:
        return len(self.gt)

    def resized(self, side: int) -> "TripletSet":
        """The set with every image and mask resized to side x side (cv2.INTER_AREA; a copy)."""
        import cv2

        if not isinstance(side, int) or side < 1:
            raise ValueError(f"side: must be a positive integer, got {side!r}")
        if self.gt.shape[1:3] == (side, side):
            return self

        def rs(a: np.ndarray) -> np.ndarray:
            return np.stack([cv2.resize(x, (side, side), interpolation=cv2.INTER_AREA) for x in a])

        return TripletSet(rs(self.gt), rs(self.mask), rs(self.coarse), rs(self.normal), self.split, self.group,
                          self.subject, self.view_yaw, None if self.aligned is None else rs(self.aligned))

    def partners(self, i: int, k_max: int) -> np.ndarray:
        """Frames T+k of the same subject and sequence with 0 < |k| <= k_max (by position in the file)."""
        lo, hi = max(0, i - k_max), min(len(self), i + k_max + 1)
        idx = np.arange(lo, hi)
        return idx[(idx != i) & (self.group[idx] == self.group[i])]

    def nearest_view(self, i: int) -> int:
        """The training frame of the same subject whose view of the body is closest to frame i's."""
        cand = np.nonzero((self.subject == self.subject[i]) & (self.split == "train"))[0]
        cand = cand[cand != i]
        if len(cand) == 0:
            raise ValueError(f"triplets: subject {self.subject[i]} has no training frame to use as reference")
        d = np.angle(np.exp(1j * (self.view_yaw[cand] - self.view_yaw[i])))
        return int(cand[np.argmin(np.abs(d))])

    def take(self, t: np.ndarray, ref: np.ndarray) -> Tuples:
        f = np.float32(1.0 / 255.0)
        aligned = None if self.aligned is None else self.aligned[t] * f
        return Tuples(self.gt[t] * f, self.coarse[t] * f, self.normal[t] * f, self.gt[ref] * f, self.mask[t] * f, aligned)

    def draw(self, rng: np.random.Generator, batch: int, k_max: int = 4, split: str | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The frame indices of a random batch, (T [batch], T+k [batch]): T uniform over the frames (of
        ``split`` if given), T+k uniform over its partners."""
        pool = np.arange(len(self)) if split is None else np.nonzero(self.split == split)[0]
        if len(pool) == 0:
            raise ValueError(f"split: no {split!r} frames in the triplets")
        t = rng.choice(pool, size=batch)
        ref = np.empty_like(t)
        for j, i in enumerate(t):
            p = self.partners(int(i), k_max)
            ref[j] = rng.choice(p) if len(p) else i
        return t, ref

    def sample(self, rng: np.random.Generator, batch: int, k_max: int = 4, split: str | None = None) -> Tuples:
        """A random batch (``draw``'s frames)."""
        return self.take(*self.draw(rng, batch, k_max, split))

    def nearby(self, split: str | None = "test", k_max: int = 4, seed: int = 0) -> Tuples:
        """Every frame T of ``split`` (None: every frame) with a GT frame T+k of its sequence
        (0 < |k| <= k_max, drawn with ``seed``) as reference: the paper's construction of the
        Examiner's pairs."""
        rng = np.random.default_rng(seed)
        t = np.arange(len(self)) if split is None else np.nonzero(self.split == split)[0]
        ref = np.array([rng.choice(p) if len(p := self.partners(int(i), k_max)) else i for i in t], dtype=np.int64)
        return self.take(t, ref)

    def evaluation(self, split: str = "test") -> Tuples:
        """Every frame of ``split`` with its nearest-view training frame as reference."""
        t = np.nonzero(self.split == split)[0]
        return self.take(t, np.array([self.nearest_view(int(i)) for i in t], dtype=np.int64))
