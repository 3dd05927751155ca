"""Offline augmentation (paper 3.2.3-3.2.6): pseudo-GT frames for a subject, without torch.

For each source frame T of a subject (default: its train split):

    generate  the Generator draws ``per_frame`` candidates (pose + camera perturbation) with a seed
              derived from (seed, T's index in the subject), so a resumed or limited run draws the
              same candidates; the real frame I^T is read
    render    the avatar at each candidate's pose and camera (numpy splat renderer, frame T's K, the
              subject's size and background): the coarse frame I_c and its alpha
    normal    the subject's body at the candidate's pose and camera: the normal map I_g (only when the
              Refiner is conditioned on geometry)
    refine    Refiner(I_c, reference I^T, normal I_g) -> I_r (all candidates in one batch)
    examine   Examiner score of every I_r against I^T; the higher-scoring candidate is kept, and
              dropped when its score < threshold. Without an Examiner every candidate is kept.
    write     the kept frames' images and masks, then the frame's record (all atomic)

The pseudo-GT mask is the avatar render's alpha A at the candidate's pose and camera, and the
pseudo-GT image is the refined frame over the subject's background through that mask,
A * I_r + (1 - A) * background, so image and mask agree as in any subject (the training loop
composites images over random backgrounds with the mask). The output
folder is a subject folder (docs/formats.md "Augmented frames") plus ``records/``, ``augment.json``
and the score histogram ``scores.png``. A frame is done when its record exists: an interrupted run
leaves only complete frames, and ``resume=True`` skips them and ends with the same files as an
uninterrupted run (``subject.json``, ``frames.npz`` and ``augment.json`` are assembled from the
records at the end; only the timings differ).

Sharded (``shard``, runtime/shards.py): shard I of N does the source frames at positions p % N == I of
the selection into its own folder ``out/shards/I-of-N`` (a resumable run like any other) and records
itself; ``merge=True`` checks every shard (finished, same settings), moves their frames and records
into ``out`` and assembles it as above: the files of a one-process run, timings aside.
"""

from __future__ import annotations

import json
import numbers
import os
import re
import shutil
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Callable, Iterable, Mapping

import cv2
import numpy as np

from trioman import __version__
from trioman.runtime.aligned import Aligner, SourceViews
from trioman.runtime.formats import FormatError, load_avatar, load_subject
from trioman.runtime.formats.avatar import AVATAR_JSON, sha256_file
from trioman.runtime.formats.common import read_json, write_npz
from trioman.runtime.formats.subject import (
    BODY_NPZ, FRAMES_NPZ, IMAGES_DIR, MASKS_DIR, WEIGHTS_DIR, SUBJECT_FORMAT, SUBJECT_JSON, SUBJECT_VERSION, check_frame_name,
    check_frames, check_subject_meta,
)
from trioman.runtime.generator import GROUPS, GeneratorConfig, joint_groups, sample
from trioman.runtime.image_io import (
    atomic_path, atomic_write_bytes, atomic_write_text, is_temp_name, remove_temp_files, write_png,
)
from trioman.runtime.pseudo_gt import STAGES as _STEP_STAGES
from trioman.runtime.pseudo_gt import MASKS, PseudoConfig, Source, make_pseudo_frames, needs_aligner
from trioman.runtime.render import rasterize
from trioman.runtime.shards import SHARDS_DIR, Shard, check_shards, shard_run

__all__ = ["AUGMENT_JSON", "RECORDS_DIR", "WEIGHTS_DIR", "HISTOGRAM_PNG", "STAGES", "augment", "frame_seed", "draw_histogram"]

AUGMENT_FORMAT = "trioman-augment"
AUGMENT_VERSION = 1
AUGMENT_JSON = "augment.json"
RECORDS_DIR = "records"
HISTOGRAM_PNG = "scores.png"
STAGES = _STEP_STAGES + ("write",)
_SHA256 = re.compile(r"[0-9a-f]{64}")  # a frame file's digest in its record (fullmatch)
# What a resumed run must share with the run it continues (everything that decides the output bytes).
_RESUME_KEYS = ("subject", "avatar", "refiner", "examiner", "seed", "per_frame", "threshold", "frames", "mask",
                "generator")


# --------------------------------------------------------------------------------------------------
# checks


def _check_options(per_frame: Any, threshold: Any, seed: Any, frames: Any, limit: Any, examiner: Any,
                   resume: bool, overwrite: bool) -> None:
    def integer(v: Any) -> bool:
        return isinstance(v, numbers.Integral) and not isinstance(v, bool)

    if not integer(per_frame) or per_frame < 1:
        raise ValueError(f"--per-frame: must be an integer >= 1, got {per_frame!r}")
    if threshold is not None:
        if isinstance(threshold, bool) or not isinstance(threshold, numbers.Real) or not 0.0 <= threshold <= 1.0:
            raise ValueError(f"--threshold: must be a number in [0, 1], got {threshold!r}")
        if examiner is None:
            raise ValueError(f"--threshold: {threshold} needs an Examiner (--examiner); without one every candidate is kept")
    if not integer(seed) or seed < 0:
        raise ValueError(f"--seed: must be an integer >= 0, got {seed!r}")
    if frames not in ("train", "all"):
        raise ValueError(f"--frames: expected 'train' or 'all', got {frames!r}")
    if limit is not None and (not integer(limit) or limit < 1):
        raise ValueError(f"--limit: must be an integer >= 1, got {limit!r}")
    if resume and overwrite:
        raise ValueError("--resume and --overwrite: choose one (continue the run in --out, or replace it)")


def _existing(path: Any, flag: str, kind: str) -> Path:
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"{flag}: {kind} not found: {p}")
    return p


def _check_out(out: Path, resume: bool, overwrite: bool) -> bool:
    """-> whether ``out`` holds earlier output (non-empty). Raises before any work when it may not be used."""
    if out.exists() and not out.is_dir():
        raise FileExistsError(f"--out: {out} exists and is not a folder")
    if not out.is_dir() or not any(out.iterdir()):
        return False
    is_augment = (out / AUGMENT_JSON).is_file()
    if not (resume or overwrite):
        raise FileExistsError(f"--out: {out} exists and is not empty (pass --resume to continue an interrupted run "
                              f"there, --overwrite to replace it, or choose another --out)")
    if not is_augment:
        action = "resume" if resume else "replace"
        raise FileExistsError(f"--out: {out} is not empty and holds no {AUGMENT_JSON}: not a `trioman augment` "
                              f"output, refusing to {action} it")
    return True


def _written_files(out: Path, source_names: Iterable[str]) -> list[Path]:
    """The files and folders in ``out`` that ``trioman augment`` wrote: the fixed names, the records, the frames
    they list, the frames of an interrupted source frame (``<source name>_c<k>.png``, no record yet) and
    temporary files. Anything else is a FileExistsError naming it: --overwrite removes only its own output."""
    fixed = {AUGMENT_JSON, SUBJECT_JSON, BODY_NPZ, FRAMES_NPZ, HISTOGRAM_PNG, IMAGES_DIR, MASKS_DIR, RECORDS_DIR,
             WEIGHTS_DIR}
    records, frames = set(), set()
    for path in (out / RECORDS_DIR).glob("*.json"):
        try:
            rec = json.loads(path.read_text(encoding="utf-8"))
            names = {f"{f['name']}.png" for f in rec["frames"]}
        except (ValueError, KeyError, TypeError):
            continue  # not a record of ours: reported below
        records.add(path.name)
        frames |= names
    orphan = re.compile("(?:" + "|".join(re.escape(n) for n in source_names) + r")_c\d+\.png")
    owned = []
    for root, dirs, files in os.walk(out):
        parts = Path(root).relative_to(out).parts
        for name in sorted(dirs) + sorted(files):
            path = Path(root) / name
            if (is_temp_name(name) or (not parts and name in fixed) or (parts == (RECORDS_DIR,) and name in records)
                    or (parts in ((IMAGES_DIR,), (MASKS_DIR,), (WEIGHTS_DIR,)) and (name in frames or orphan.fullmatch(name)))):
                owned.append(path)
            else:
                raise FileExistsError(f"--overwrite: {path} was not written by trioman augment; refusing to replace "
                                      f"{out} (move it away, or choose another --out)")
        dirs[:] = [d for d in dirs if not is_temp_name(d)]
    return owned


def _check_joints(avatar: Any, subject: Any, avatar_path: Path) -> None:
    a, s = avatar.skeleton.joint_names, subject.body.skeleton.joint_names
    if len(a) != len(s):
        raise ValueError(f"--avatar: {avatar_path} has {len(a)} joints, but the subject's body has {len(s)} joints "
                         f"(the avatar must be trained on this subject's body)")
    if a != s:
        j = next(k for k in range(len(a)) if a[k] != s[k])
        raise ValueError(f"--avatar: joint {j} is {a[j]!r} in {avatar_path}, but {s[j]!r} in the subject's body "
                         f"(the avatar must be trained on this subject's body)")


def frame_seed(seed: int, index: int) -> int:
    """The Generator seed of source frame ``index`` (its index in the subject) for the run seed ``seed``."""
    return int(np.random.SeedSequence([int(seed), int(index)]).generate_state(1, np.uint64)[0])


# --------------------------------------------------------------------------------------------------
# settings and provenance


def _model_info(model: Any, path: Path) -> dict[str, Any]:
    meta = dict(model.meta)
    return {"path": str(path.resolve()), "sha256": sha256_file(path), "size": list(model.size),
            "config_hash": meta.get("trioman.config_hash"), "precision": meta.get("trioman.precision"),
            "kind": meta.get("trioman.kind"), "version": meta.get("trioman.version")}


def _settings(subject: Any, avatar: Any, avatar_path: Path, refiner: Any, refiner_path: Path | None, examiner: Any,
              examiner_path: Path | None, seed: int, per_frame: int, threshold: float | None, frames: str,
              gen_cfg: GeneratorConfig, mask: str) -> dict[str, Any]:
    source = dict(avatar.meta.get("source", {}))
    ref = None
    if refiner is not None:
        ref = _model_info(refiner, refiner_path)
        ref["conditions"] = refiner.conditions
    return {
        "subject": {"path": str(Path(subject.root).resolve()),
                    "frames_sha256": sha256_file(Path(subject.root) / FRAMES_NPZ)},
        "avatar": {"path": str(avatar_path.resolve()), "avatar_json_sha256": sha256_file(avatar_path / AVATAR_JSON),
                   "step": source.get("step"), "run": source.get("run"), "num_gaussians": avatar.num_gaussians},
        "refiner": ref,
        "examiner": None if examiner is None else _model_info(examiner, examiner_path),
        "seed": int(seed),
        "per_frame": int(per_frame),
        "threshold": None if threshold is None else float(threshold),
        "frames": frames,
        "mask": mask,
        "generator": json.loads(json.dumps(asdict(gen_cfg))),
    }


def _versions() -> dict[str, str]:
    import onnxruntime

    return {"trioman": __version__, "numpy": np.__version__, "opencv": cv2.__version__,
            "onnxruntime": onnxruntime.__version__}


def _check_resume(out: Path, settings: Mapping[str, Any]) -> None:
    try:
        old = json.loads((out / AUGMENT_JSON).read_text(encoding="utf-8"))["settings"]
    except (OSError, ValueError, KeyError, TypeError) as err:
        raise FormatError(f"{out / AUGMENT_JSON}: unreadable settings of the earlier run ({err})") from None
    for key in _RESUME_KEYS:
        if old.get(key) != settings[key]:
            raise ValueError(f"--resume: {key} differs from the run in {out} (was {old.get(key)!r}, now "
                             f"{settings[key]!r}); use the same inputs, or --overwrite to start again")


def _dump(obj: Any) -> str:
    return json.dumps(obj, indent=2, allow_nan=False) + "\n"


# --------------------------------------------------------------------------------------------------
# records


def _record_path(out: Path, name: str) -> Path:
    return out / RECORDS_DIR / f"{name}.json"


def _read_record(out: Path, name: str, index: int) -> dict[str, Any] | None:
    """A finished frame's record, or None when the frame must be (re)done."""
    path = _record_path(out, name)
    if not path.is_file():
        return None
    try:
        rec = json.loads(path.read_text(encoding="utf-8"))
        ok = rec["version"] == AUGMENT_VERSION and rec["source"]["index"] == index
        files = [out / d / f"{f['name']}.png" for f in rec["frames"]
                 for d in (IMAGES_DIR, MASKS_DIR) + ((WEIGHTS_DIR,) if f.get("weights") else ())]
    except (OSError, ValueError, KeyError, TypeError):
        return None
    return rec if ok and all(f.is_file() for f in files) else None


def _group_norms(delta: np.ndarray, groups: np.ndarray) -> dict[str, float]:
    """Frobenius norm of the pose change per joint group (radians)."""
    return {g: float(np.linalg.norm(delta[groups == g])) for g in GROUPS if np.any(groups == g)}


# --------------------------------------------------------------------------------------------------
# the run


def augment(
    subject: str | os.PathLike,
    avatar: str | os.PathLike,
    refiner: str | os.PathLike | None,
    out: str | os.PathLike,
    examiner: str | os.PathLike | None = None,
    *,
    per_frame: int = 2,
    threshold: float | None = None,
    seed: int = 0,
    frames: str = "train",
    limit: int | None = None,
    resume: bool = False,
    overwrite: bool = False,
    generator: GeneratorConfig | None = None,
    threads: int | None = None,
    progress: bool = True,
    shard: Shard | None = None,
    merge: bool = False,
    mask: str = "carried",
) -> dict[str, Any]:
    """Write pseudo-GT frames of ``subject`` (folder) made with ``avatar`` (folder), the Refiner and the
    optional Examiner (ONNX files) into the folder ``out`` (module doc). -> the augment.json content.
    Without a Refiner (``refiner=None``) the frames are the aligned kind (runtime/pseudo_gt.py): the render
    with real pixels carried through the body mesh, with per-pixel loss weights in ``out/weights``.

    frames: source frames, "train" (the train split) or "all"; limit: the first ``limit`` of them.
    threshold: drop the chosen candidate when its Examiner score is below it (needs an Examiner).
    mask: the pseudo frames' mask, "carried" (the body mesh and the source frame's mask carried to the draw) or
    "alpha" (the avatar render's own alpha); runtime/pseudo_gt.py.
    Every input is checked before any work; a bad one raises ValueError / FileNotFoundError /
    FileExistsError / FormatError naming the option and the value.
    shard: do only that shard's frames, in out/shards/I-of-N (-> its record); merge: assemble ``out``
    from every shard's (module doc).
    """
    from trioman.runtime.models import ExaminerModel, RefinerModel

    _check_options(per_frame, threshold, seed, frames, limit, examiner, resume, overwrite)
    if mask not in MASKS:
        raise ValueError(f"--mask: expected one of {MASKS}, got {mask!r}")
    gen_cfg = generator if generator is not None else GeneratorConfig()
    if not isinstance(gen_cfg, GeneratorConfig):
        raise ValueError(f"generator: expected a GeneratorConfig, got {type(gen_cfg).__name__}")
    subject_path = _existing(subject, "SUBJECT", "subject folder")
    avatar_path = _existing(avatar, "--avatar", "avatar folder")
    refiner_path = None if refiner is None else _existing(refiner, "--refiner", "Refiner ONNX file")
    if refiner is None and examiner is not None:
        raise ValueError("--examiner: chooses among refined candidates; give --refiner too (without a Refiner the "
                         "pseudo-GT is the aligned kind: the render with real pixels carried through the body mesh)")
    examiner_path = None if examiner is None else _existing(examiner, "--examiner", "Examiner ONNX file")
    if shard is not None and merge:
        raise ValueError("--merge: runs after the --shard jobs, not with --shard")
    out = Path(out)
    top, out = out, (out / SHARDS_DIR / shard.name if shard is not None else out)
    had_output = False if merge else _check_out(out, resume, overwrite)

    subj = load_subject(subject_path)
    earlier = _written_files(out, subj.frame_names.tolist()) if had_output and overwrite else []  # refused first
    views_of = subj.indices("train" if frames == "train" else None)  # the frames real pixels are carried from
    if len(views_of) == 0:
        raise ValueError(f"--frames: subject {subject_path} has no {frames!r} frames")
    selection = views_of[:limit] if limit is not None else views_of
    av = load_avatar(avatar_path)
    _check_joints(av, subj, avatar_path)
    ref_model = None if refiner_path is None else RefinerModel(refiner_path, threads=threads)
    H, W = subj.height, subj.width
    if ref_model is not None and tuple(ref_model.size) != (H, W):
        h, w = ref_model.size
        how = (f"trioman export onnx --refiner CKPT --size {H}" if H == W
               else f"export_refiner_onnx(CKPT, PATH, size=({H}, {W}))")
        raise ValueError(f"--refiner: {refiner_path} takes {h}x{w} (H x W) images, but the subject's images are "
                         f"{H}x{W}; export the Refiner at the subject's size ({how})")
    ex_model = None if examiner_path is None else ExaminerModel(examiner_path, threads=threads)
    kind = "aligned" if ref_model is None else "refined" if ex_model is None else "examined"
    pseudo = PseudoConfig(kind=kind, mask=mask, threshold=threshold)
    settings = _settings(subj, av, avatar_path, ref_model, refiner_path, ex_model, examiner_path, seed, per_frame,
                         threshold, frames, gen_cfg, mask)
    if had_output and resume:
        _check_resume(out, settings)
    names = [str(subj.frame_names[i]) for i in selection]
    if merge:
        return _merge(out, subj, selection, check_shards(out, {**settings, "limit": limit}), settings, ex_model is not None,
                      threshold)
    step = _Step(av, ref_model, ex_model, _aligner(subj, views_of, pseudo, ref_model), pseudo,
                 {int(i): p for p, i in enumerate(views_of)}, seed, per_frame, gen_cfg)
    if shard is not None:
        with shard_run(top, shard, {**settings, "limit": limit}, shard.take(names)):
            _run(out, subj, shard.take(selection.tolist()), step, earlier, had_output, resume, settings, progress)
        return json.loads(shard.record_path(top).read_text(encoding="utf-8"))
    return _run(out, subj, selection.tolist(), step, earlier, had_output, resume, settings, progress, finish=True)


@dataclass(frozen=True)
class _Step:
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


def _aligner(subj: Any, indices: np.ndarray, pseudo: PseudoConfig, refiner: Any) -> Aligner | None:
    """The aligned reference over the subject's frames ``indices`` (when the pseudo-GT needs it)."""
    if not needs_aligner(pseudo, None if refiner is None else refiner.conditions):
        return None
    return Aligner(subj.body, SourceViews.of_subject(subj, indices))


def _run(out: Path, subj: Any, selection: list[int], step: _Step, earlier: list[Path], had_output: bool, resume: bool,
         settings: dict[str, Any], progress: bool, finish: bool = False) -> dict[str, Any] | None:
    """The frames of ``selection`` into ``out`` (resuming finished ones); with ``finish`` the assembled
    subject and augment.json (-> its content)."""
    from tqdm import tqdm

    # ---- work starts here
    for path in earlier:  # --overwrite: only what augment wrote (its folders stay)
        if path.is_file():
            path.unlink()
        elif is_temp_name(path.name):
            shutil.rmtree(path)
    if had_output and resume:
        remove_temp_files(out)  # an interrupted write's leftovers
    for d in (out, out / IMAGES_DIR, out / MASKS_DIR, out / RECORDS_DIR) + ((out / WEIGHTS_DIR,) if step.weighted else ()):
        d.mkdir(parents=True, exist_ok=True)
    for name in (SUBJECT_JSON,):  # the folder is not a loadable subject while the run is going
        (out / name).unlink(missing_ok=True)
    header = {"format": AUGMENT_FORMAT, "version": AUGMENT_VERSION, "status": "running", "settings": settings,
              "versions": _versions()}
    atomic_write_text(out / AUGMENT_JSON, _dump(header))

    groups = np.array(joint_groups(subj.body.skeleton))
    records: list[dict[str, Any]] = []
    computed = 0
    start = time.perf_counter()
    bar = tqdm(selection, desc="augment", unit="frame", disable=None if progress else True)
    accepted = 0
    for i in bar:
        name = str(subj.frame_names[i])
        rec = _read_record(out, name, i) if had_output else None
        if rec is None:
            rec = _augment_frame(subj, i, step, out, groups)
            computed += 1
        records.append(rec)
        accepted += len(rec["frames"])
        bar.set_postfix(kept=accepted)
    bar.close()
    seconds = time.perf_counter() - start
    if not finish:
        return None
    return _finish(out, subj, records, settings, header, step.examiner is not None, step.pseudo.threshold, computed,
                   seconds)


def _merge(out: Path, subj: Any, selection: np.ndarray, shards: list[dict[str, Any]], settings: dict[str, Any],
           with_examiner: bool, threshold: float | None) -> dict[str, Any]:
    """Check every shard's records and files, then move them into ``out`` (a record last, so a merge can be
    rerun), assemble ``out`` from the records in selection order and remove out/shards. A malformed record
    or a missing file is a FormatError naming it, raised before anything moves."""
    start = time.perf_counter()
    index_of = {str(subj.frame_names[i]): int(i) for i in selection.tolist()}
    moves: list[tuple[Path, Path]] = []
    for rec in shards:
        folder = out / SHARDS_DIR / Shard.parse(rec["shard"]).name
        for name in rec["items"]:
            src = _record_path(folder, name)
            if not src.is_file():
                if _record_path(out, name).is_file():  # moved by an earlier merge
                    continue
                raise ValueError(f"--merge: shard {rec['shard']} has no record for frame {name} ({src})")
            for f in check_record(read_json(src), src, folder, name, index_of.get(name, -1))["frames"]:
                for sub in (IMAGES_DIR, MASKS_DIR) + ((WEIGHTS_DIR,) if f.get("weights") else ()):
                    moves.append((folder / sub / f"{f['name']}.png", out / sub / f"{f['name']}.png"))
            moves.append((src, _record_path(out, name)))
    for d in (out / IMAGES_DIR, out / MASKS_DIR, out / RECORDS_DIR, out / WEIGHTS_DIR):
        d.mkdir(parents=True, exist_ok=True)
    for src, dst in moves:
        os.replace(src, dst)
    records = []
    for i in selection.tolist():
        rec = _read_record(out, str(subj.frame_names[i]), i)
        if rec is None:
            raise ValueError(f"--merge: frame {subj.frame_names[i]} has no complete record in {out / RECORDS_DIR}")
        records.append(rec)
    header = {"format": AUGMENT_FORMAT, "version": AUGMENT_VERSION, "status": "running", "settings": settings,
              "versions": _versions()}
    result = _finish(out, subj, records, settings, header, with_examiner, threshold, 0, time.perf_counter() - start)
    shutil.rmtree(out / SHARDS_DIR)
    return result


def check_record(rec: Any, path: Path, folder: Path, name: str, index: int) -> dict[str, Any]:
    """A source frame's record as augment writes it, its frames' files present in ``folder``: -> ``rec``; a
    FormatError naming ``path`` and the field otherwise (a merge reads records another job wrote)."""
    def fail(field: str, why: str) -> FormatError:
        return FormatError(f"{path}: {field}: {why}")

    if not isinstance(rec, dict):
        raise fail("record", f"expected a JSON object, got {type(rec).__name__}")
    if rec.get("version") != AUGMENT_VERSION:
        raise fail("version", f"expected {AUGMENT_VERSION}, got {rec.get('version')!r}")
    source = rec.get("source")
    if not isinstance(source, dict) or source.get("name") != name or source.get("index") != index:
        raise fail("source", f"expected frame {name!r} (index {index}), got {source!r}")
    if isinstance(rec.get("seed"), bool) or not isinstance(rec.get("seed"), int):
        raise fail("seed", f"expected an integer, got {rec.get('seed')!r}")
    candidates, frames = rec.get("candidates"), rec.get("frames")
    if not isinstance(candidates, list) or not isinstance(frames, list):
        raise fail("candidates/frames", "expected lists")
    for k, c in enumerate(candidates):
        score = c.get("score") if isinstance(c, dict) else "not an object"
        if score is not None and (isinstance(score, bool) or not isinstance(score, (int, float))
                                  or not 0.0 <= score <= 1.0):
            raise fail(f"candidates[{k}].score", f"expected null or a number in [0, 1], got {score!r}")
    shapes = {"pose": None, "trans": (3,), "viewmat": (4, 4), "K": (3, 3)}
    for k, f in enumerate(frames):
        if not isinstance(f, dict):
            raise fail(f"frames[{k}]", "expected an object")
        check_frame_name(f.get("name"), path, f"frames[{k}].name")
        for key, shape in shapes.items():
            try:
                a = np.asarray(f.get(key), dtype=np.float64)
            except (TypeError, ValueError):
                raise fail(f"frames[{k}].{key}", "expected numbers") from None
            if (shape is not None and a.shape != shape) or a.size == 0 or not np.isfinite(a).all():
                raise fail(f"frames[{k}].{key}", f"expected finite numbers of shape {shape or '[J, 3]'}, got {list(a.shape)}")
        subs = (IMAGES_DIR, MASKS_DIR) + ((WEIGHTS_DIR,) if f.get("weights") else ())
        for sub in subs:
            if not (folder / sub / f"{f['name']}.png").is_file():
                raise fail(f"frames[{k}]", f"its file {folder / sub / (f['name'] + '.png')} is missing")
        if "sha256" in f:  # records written before the hashes were kept have none, and stay readable
            _check_frame_hashes(f["sha256"], subs, folder, f["name"], fail, f"frames[{k}].sha256")
    return rec


def _check_frame_hashes(digests: Any, subs: tuple[str, ...], folder: Path, name: str, fail: Callable[[str, str], FormatError],
                        field: str) -> None:
    """Each of a frame's files (``folder/<sub>/<name>.png``) has the sha256 its record gives (``digests``:
    {sub: hex digest}, one per file): a file replaced or damaged after it was written is named."""
    if not isinstance(digests, dict) or sorted(digests) != sorted(subs) or not all(
            isinstance(d, str) and _SHA256.fullmatch(d) for d in digests.values()):
        raise fail(field, f"expected {{{', '.join(repr(s) for s in subs)}}} each a sha256 (64 hex digits), got {digests!r}")
    for sub in subs:
        path = folder / sub / f"{name}.png"
        found = sha256_file(path)
        if found != digests[sub]:
            raise fail(f"{field}.{sub}", f"{path} is not the file that was written (its sha256 is {found[:12]}..., the "
                                         f"record's {digests[sub][:12]}...): replaced or damaged since")


def _write_frame_png(path: Path, img: np.ndarray) -> str:
    """Write a frame file (atomic) -> the sha256 of its bytes as written, kept in the record (check_record
    verifies it)."""
    write_png(path, img)
    return sha256_file(path)


def _augment_frame(subj: Any, i: int, step: _Step, out: Path, groups: np.ndarray) -> dict:
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
    atomic_write_text(_record_path(out, name), _dump(rec))
    return rec


# --------------------------------------------------------------------------------------------------
# assembly


def _stats(values: list[float]) -> dict[str, Any]:
    if not values:
        return {"count": 0, "mean": None, "min": None, "max": None}
    a = np.asarray(values, dtype=np.float64)
    return {"count": int(a.size), "mean": float(a.mean()), "min": float(a.min()), "max": float(a.max())}


def _write_subject(out: Path, subj: Any, frames: list[dict[str, Any]], records: list[dict[str, Any]],
                   settings: Mapping[str, Any]) -> None:
    """frames.npz, body.npz (the source's bytes) and subject.json of the accepted frames, each atomic."""
    seqs = [str(subj.sequence[r["source"]["index"]]) for r in records for _ in r["frames"]]
    meta = {
        "format": SUBJECT_FORMAT, "version": SUBJECT_VERSION, "body_model": subj.body_model, "units": "m",
        "up_axis": "z", "width": subj.width, "height": subj.height, "num_frames": len(frames),
        "background": [float(c) for c in subj.meta["background"]],
        "phenotype": dict(subj.meta.get("phenotype", {})),
        "generator": {"tool": "trioman augment", "version": __version__, "source_subject": settings["subject"]["path"],
                      "avatar": settings["avatar"]["path"], "seed": settings["seed"],
                      "per_frame": settings["per_frame"], "threshold": settings["threshold"],
                      "examiner": settings["examiner"] is not None,
                      "kind": "aligned" if settings["refiner"] is None else "refined",
                      "mask": {"carried": "body mesh and source mask carried to the draw",
                               "alpha": "avatar render alpha"}[settings.get("mask", "alpha")]},
        "sequences": list(dict.fromkeys(seqs)),
    }
    where = out / SUBJECT_JSON
    check_subject_meta(meta, where)
    arrays = {
        "poses": np.array([f["pose"] for f in frames], dtype=np.float32),
        "trans": np.array([f["trans"] for f in frames], dtype=np.float32),
        "K": np.array([f["K"] for f in frames], dtype=np.float32),
        "viewmat": np.array([f["viewmat"] for f in frames], dtype=np.float32),
        "split": np.array(["train"] * len(frames), dtype=np.str_),
        "sequence": np.array(seqs, dtype=np.str_),
        "frame_names": np.array([f["name"] for f in frames], dtype=np.str_),
    }
    arrays = check_frames(arrays, out / FRAMES_NPZ, len(frames), subj.num_joints, meta["sequences"])
    atomic_write_bytes(out / BODY_NPZ, (Path(subj.root) / BODY_NPZ).read_bytes())
    with atomic_path(out / FRAMES_NPZ) as tmp:
        write_npz(tmp, arrays)
    atomic_write_text(where, _dump(meta))  # last: a folder with subject.json is a complete subject


def _finish(out: Path, subj: Any, records: list[dict[str, Any]], settings: dict[str, Any], header: dict[str, Any],
            with_examiner: bool, threshold: float | None, computed: int, seconds: float) -> dict[str, Any]:
    frames = [f for r in records for f in r["frames"]]
    candidates = [c for r in records for c in r["candidates"]]
    by_status: dict[str, list[float]] = {s: [c["score"] for c in candidates if c["status"] == s]
                                         for s in ("accepted", "rejected", "not_chosen")}
    summary: dict[str, Any] = {
        "source_frames": len(records),
        "candidates": len(candidates),
        "frames_written": len(frames),
        "accepted": len(frames),
        "rejected": sum(1 for r in records if not r["kept"]),
        "not_chosen": len(by_status["not_chosen"]),
        "scores": _stats([c["score"] for c in candidates if c["score"] is not None]),
        "chosen_scores": _stats(by_status["accepted"] + by_status["rejected"]),
    }
    if frames:
        _write_subject(out, subj, frames, records, settings)
        summary["subject_written"] = True
        summary["note"] = f"{len(frames)} pseudo-GT frames written as a subject (this folder)"
    else:
        for name in (SUBJECT_JSON, FRAMES_NPZ, BODY_NPZ):
            (out / name).unlink(missing_ok=True)
        summary["subject_written"] = False
        summary["note"] = "0 accepted: no pseudo-GT subject written (a subject needs at least one frame)"
    hist = out / HISTOGRAM_PNG
    if with_examiner:
        draw_histogram(by_status, threshold, hist)
        summary["histogram"] = HISTOGRAM_PNG  # relative to the output folder
    else:
        hist.unlink(missing_ok=True)
        summary["histogram"] = None
    n = max(len(records), 1)
    timing = {
        "ms_per_source_frame": {s: 1000.0 * sum(r["seconds"][s] for r in records) / n for s in STAGES},
        "frames_computed": computed,
        "frames_resumed": len(records) - computed,
        "seconds_this_call": seconds,
    }
    timing["ms_per_source_frame"]["total"] = sum(timing["ms_per_source_frame"].values())
    result = dict(header, status="complete", summary=summary, timing=timing)
    atomic_write_text(out / AUGMENT_JSON, _dump(result))
    return result


# --------------------------------------------------------------------------------------------------
# the histogram (OpenCV; no matplotlib in the runtime)

_COLORS = {"accepted": (46, 160, 67), "rejected": (214, 39, 40), "not_chosen": (170, 170, 170)}  # RGB
_LABELS = {"accepted": "accepted", "rejected": "rejected (below threshold)", "not_chosen": "not chosen"}


def draw_histogram(scores: Mapping[str, list[float]], threshold: float | None, path: str | os.PathLike,
                   bins: int = 20, size: tuple[int, int] = (640, 400)) -> Path:
    """Stacked histogram of Examiner scores in [0, 1] by status (accepted / rejected / not chosen), the
    threshold as a vertical line; an 8-bit RGB PNG written atomically at ``path``."""
    W, H = size
    img = np.full((H, W, 3), 255, np.uint8)
    left, right, top, bottom = 56, 20, 70, 48
    pw, ph = W - left - right, H - top - bottom
    edges = np.linspace(0.0, 1.0, bins + 1)
    counts = {k: np.histogram(np.clip(np.asarray(v, dtype=np.float64), 0.0, 1.0), bins=edges)[0]
              for k, v in scores.items() if k in _COLORS}
    total = sum(counts.values()) if counts else np.zeros(bins, int)
    ymax = max(int(np.max(total)) if np.size(total) else 0, 1)
    font, black, grey = cv2.FONT_HERSHEY_SIMPLEX, (0, 0, 0), (200, 200, 200)

    def x_of(v: float) -> int:
        return left + int(round(v * pw))

    def y_of(c: float) -> int:
        return top + ph - int(round(c / ymax * ph))

    for frac in (0.25, 0.5, 0.75, 1.0):  # grid
        cv2.line(img, (left, y_of(frac * ymax)), (left + pw, y_of(frac * ymax)), grey, 1)
    for b in range(bins):
        base = 0
        for k in ("accepted", "rejected", "not_chosen"):
            c = int(counts[k][b]) if k in counts else 0
            if c:
                cv2.rectangle(img, (x_of(edges[b]) + 1, y_of(base + c)), (x_of(edges[b + 1]) - 1, y_of(base) - 1),
                              _COLORS[k], -1)
                base += c
    cv2.line(img, (left, top + ph), (left + pw, top + ph), black, 1)  # axes
    cv2.line(img, (left, top), (left, top + ph), black, 1)
    for v in (0.0, 0.25, 0.5, 0.75, 1.0):
        cv2.line(img, (x_of(v), top + ph), (x_of(v), top + ph + 4), black, 1)
        cv2.putText(img, f"{v:g}", (x_of(v) - 10, top + ph + 18), font, 0.4, black, 1, cv2.LINE_AA)
    for c in sorted({0, ymax // 2, ymax}):
        cv2.putText(img, str(c), (left - 8 - 8 * len(str(c)), y_of(c) + 4), font, 0.4, black, 1, cv2.LINE_AA)
    cv2.putText(img, "Examiner score", (left + pw // 2 - 50, H - 12), font, 0.45, black, 1, cv2.LINE_AA)
    cv2.putText(img, "candidates", (4, top - 10), font, 0.4, black, 1, cv2.LINE_AA)
    if threshold is not None:
        x = x_of(float(threshold))
        for y in range(top, top + ph, 8):  # dashed
            cv2.line(img, (x, y), (x, min(y + 4, top + ph)), (31, 119, 180), 2)
        cv2.putText(img, f"threshold {threshold:.3g}", (min(x + 4, W - 110), top + 12), font, 0.4, (31, 119, 180), 1,
                    cv2.LINE_AA)
    n_all = sum(len(v) for v in scores.values())
    cv2.putText(img, f"Examiner scores of {n_all} refined candidates", (8, 20), font, 0.5, black, 1, cv2.LINE_AA)
    x = 8
    for k in ("accepted", "rejected", "not_chosen"):
        n = len(scores.get(k, []))
        cv2.rectangle(img, (x, 32), (x + 12, 44), _COLORS[k], -1)
        label = f"{_LABELS[k]} {n}"
        cv2.putText(img, label, (x + 16, 43), font, 0.4, black, 1, cv2.LINE_AA)
        x += 16 + cv2.getTextSize(label, font, 0.4, 1)[0][0] + 16
    path = Path(path)
    write_png(path, img)
    return path
