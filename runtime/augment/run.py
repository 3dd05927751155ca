"""``augment()``, the library of ``trioman augment``: every argument checked before any work, then the loop over
the source frames (one process, one shard, or the merge of the shards)."""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import time
from pathlib import Path
from typing import Any

import numpy as np

from trioman.runtime.aligned import AlignConfig
from trioman.runtime.augment.assemble import finish
from trioman.runtime.augment.checks import check_joints, check_keep_carried, check_options, check_out, existing, written_files
from trioman.runtime.augment.layout import AUGMENT_JSON, RECORDS_DIR, dump, running_header
from trioman.runtime.augment.merge import merge as merge_shards
from trioman.runtime.augment.records import read_record
from trioman.runtime.augment.settings import check_resume, run_settings
from trioman.runtime.augment.step import Step, augment_frame, make_aligner
from trioman.runtime.augment_options import AugmentOptions
from trioman.runtime.formats import load_avatar, load_subject
from trioman.runtime.formats.subject import IMAGES_DIR, MASKS_DIR, SUBJECT_JSON, WEIGHTS_DIR
from trioman.runtime.generator import GeneratorConfig, joint_groups
from trioman.runtime.outputs import atomic_write_text, check_not_input, is_temp_name, process_lock, remove_temp_files
from trioman.runtime.pretrained import SHIPPED, resolve_model
from trioman.runtime.pseudo_gt import MASKS, PseudoConfig
from trioman.runtime.shards import SHARDS_DIR, Shard, check_shards, shard_run


def augment(
    subject: str | os.PathLike,
    avatar: str | os.PathLike,
    refiner: str | os.PathLike | None,
    out: str | os.PathLike,
    examiner: str | os.PathLike | None = SHIPPED,
    *,
    per_frame: int = AugmentOptions.per_frame,
    threshold: float | None = AugmentOptions.threshold,
    seed: int = AugmentOptions.seed,
    frames: str = AugmentOptions.frames,
    limit: int | None = AugmentOptions.limit,
    resume: bool = False,
    overwrite: bool = False,
    generator: GeneratorConfig | None = None,
    threads: int | None = AugmentOptions.threads,
    progress: bool = True,
    shard: Shard | None = None,
    merge: bool = False,
    mask: str = AugmentOptions.mask,
    keep_carried: bool | None = AugmentOptions.keep_carried,
    texture: int = AugmentOptions.texture,
) -> dict[str, Any]:
    """Write pseudo-GT frames of ``subject`` (folder) made with ``avatar`` (folder), the Refiner and the
    optional Examiner (ONNX files; ``"shipped"``: the package's, runtime/pretrained.py; ``"none"``: none) into the
    folder ``out`` (package doc). -> the augment.json content.
    Without a Refiner (``refiner`` None or "none") the frames are the aligned kind (runtime/pseudo_gt.py): the render
    with real pixels carried through the body mesh, with per-pixel loss weights in ``out/weights``.

    frames: source frames, "train" (the train split) or "all"; limit: the first ``limit`` of them.
    threshold: drop the chosen candidate when its Examiner score is below it (needs an Examiner).
    mask: the pseudo frames' mask, "carried" (the body mesh and the source frame's mask carried to the draw) or
    "alpha" (the avatar render's own alpha); runtime/pseudo_gt.py.
    keep_carried: with a Refiner, keep the real pixels carried to the draw and take the Refiner's output only
    where nothing was carried (``PseudoConfig.keep_carried``); None (default): whenever there is a Refiner.
    texture: > 0, the aligned reference's colour from a texture of that side fused from every source frame where
    its texels were seen (``AlignConfig.texture``); 0: carried pixels only.
    Every input is checked before any work; a bad one raises ValueError / FileNotFoundError /
    FileExistsError / FormatError naming the parameter and the value.
    shard: do only that shard's frames, in out/shards/I-of-N (-> its record); merge: assemble ``out``
    from every shard's (package doc).
    """
    from trioman.runtime.onnx_models import ExaminerModel, RefinerModel

    check_options(per_frame, threshold, seed, frames, limit, examiner, resume, overwrite)
    if mask not in MASKS:
        raise ValueError(f"mask: expected one of {MASKS}, got {mask!r}")
    gen_cfg = generator if generator is not None else GeneratorConfig()
    if not isinstance(gen_cfg, GeneratorConfig):
        raise ValueError(f"generator: expected a GeneratorConfig, got {type(gen_cfg).__name__}")
    refiner = resolve_model(refiner, "refiner")
    # the shipped Examiner goes with a Refiner: without one (none) the default Examiner has nothing to choose from
    examiner = None if refiner is None and str(examiner) == SHIPPED else resolve_model(examiner, "examiner")
    subject_path = existing(subject, "subject", "subject folder")
    avatar_path = existing(avatar, "avatar", "avatar folder")
    refiner_path = None if refiner is None else existing(refiner, "refiner", "Refiner ONNX file")
    if refiner is None and examiner is not None:
        raise ValueError("examiner: chooses among refined candidates; give `refiner` too (without a Refiner the "
                         "pseudo-GT is the aligned kind: the render with real pixels carried through the body mesh)")
    check_keep_carried(keep_carried, refiner)
    AlignConfig(texture=texture)  # checks it
    keep_carried = refiner is not None if keep_carried is None else keep_carried
    examiner_path = None if examiner is None else existing(examiner, "examiner", "Examiner ONNX file")
    if shard is not None and merge:
        raise ValueError("merge: runs after the `shard` jobs, not with `shard`")
    out = Path(out)
    try:  # the output never is, holds or enters what augment reads
        check_not_input(out, [subject_path, avatar_path, refiner_path, examiner_path])
    except ValueError as err:
        raise ValueError(f"out: {err}") from None
    # one writer per output: a second run into the same folder is refused before it reads or removes anything
    # (shard jobs hold their shard's lock instead; the lock lies beside the output, which it would otherwise fill)
    lock = (process_lock(out.parent / f".{out.name}.augment.lock", f"out: another `augment` run into {out}")
            if shard is None and not merge else contextlib.nullcontext())
    with lock:
        top, out = out, (out / SHARDS_DIR / shard.name if shard is not None else out)
        had_output = False if merge else check_out(out, resume, overwrite)

        subj = load_subject(subject_path)
        earlier = written_files(out, subj.frame_names.tolist()) if had_output and overwrite else []  # refused first
        views_of = subj.indices("train" if frames == "train" else None)  # the frames real pixels are carried from
        if len(views_of) == 0:
            raise ValueError(f"frames: subject {subject_path} has no {frames!r} frames")
        selection = views_of[:limit] if limit is not None else views_of
        av = load_avatar(avatar_path)
        check_joints(av, subj, avatar_path)
        ref_model = None if refiner_path is None else RefinerModel(refiner_path, threads=threads)
        H, W = subj.height, subj.width
        if ref_model is not None and not ref_model.takes(H, W):
            h, w = ref_model.size
            raise ValueError(f"refiner: {refiner_path} takes {h}x{w} (H x W) images only, but the subject's images are "
                             f"{H}x{W}; export the Refiner again (trioman export onnx --refiner CKPT): an export with "
                             f"`trioman.size_multiple` takes any size")
        ex_model = None if examiner_path is None else ExaminerModel(examiner_path, threads=threads)
        kind = "aligned" if ref_model is None else "refined" if ex_model is None else "examined"
        pseudo = PseudoConfig(kind=kind, mask=mask, threshold=threshold, keep_carried=keep_carried)
        settings = run_settings(subj, av, avatar_path, ref_model, refiner_path, ex_model, examiner_path, seed, per_frame,
                                threshold, frames, gen_cfg, mask, keep_carried)
        if texture:
            settings["texture"] = texture
        if had_output and resume:
            check_resume(out, settings)
        names = [str(subj.frame_names[i]) for i in selection]
        if merge:
            return merge_shards(out, subj, selection, check_shards(out, {**settings, "limit": limit}), settings,
                                ex_model is not None, threshold)
        step = Step(av, ref_model, ex_model, make_aligner(subj, views_of, pseudo, ref_model, texture), pseudo,
                    {int(i): p for p, i in enumerate(views_of)}, seed, per_frame, gen_cfg)
        if shard is not None:
            with shard_run(top, shard, {**settings, "limit": limit}, shard.take(names)):
                _run(out, subj, shard.take(selection.tolist()), step, earlier, had_output, resume, settings, progress)
            return json.loads(shard.record_path(top).read_text(encoding="utf-8"))
        return _run(out, subj, selection.tolist(), step, earlier, had_output, resume, settings, progress, complete=True)


def _run(out: Path, subj: Any, selection: list[int], step: Step, earlier: list[Path], had_output: bool, resume: bool,
         settings: dict[str, Any], progress: bool, complete: bool = False) -> dict[str, Any] | None:
    """The frames of ``selection`` into ``out`` (resuming finished ones); with ``complete`` the assembled
    subject and augment.json (-> its content)."""
    from tqdm import tqdm

    # ---- work starts here
    for path in earlier:  # overwrite: only what augment wrote (its folders stay)
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
    header = running_header(settings)
    atomic_write_text(out / AUGMENT_JSON, dump(header))

    groups = np.array(joint_groups(subj.body.skeleton))
    records: list[dict[str, Any]] = []
    computed = 0
    start = time.perf_counter()
    bar = tqdm(selection, desc="augment", unit="frame", disable=None if progress else True)
    accepted = 0
    try:
        for i in bar:
            name = str(subj.frame_names[i])
            rec = read_record(out, name, i) if had_output else None
            if rec is None:
                rec = augment_frame(subj, i, step, out, groups)
                computed += 1
            records.append(rec)
            accepted += len(rec["frames"])
            bar.set_postfix(kept=accepted)
    except BaseException as err:  # augment.json says the run stopped, and why (the finished frames stay: --resume)
        with contextlib.suppress(OSError):  # a full disk: the error that stopped the run is the one to report
            atomic_write_text(out / AUGMENT_JSON, dump({**header, "status": "failed", "error": f"{type(err).__name__}: {err}"}))
        raise
    finally:
        bar.close()
    seconds = time.perf_counter() - start
    if not complete:
        return None
    return finish(out, subj, records, settings, header, step.examiner is not None, step.pseudo.threshold, computed,
                  seconds)
