"""A run's record (run/config.json) and the checks before a run is resumed.

config.json names what decides a run's weights: the subject (path and content hash), the extra frames'
content hash, the training config (and its hash), the code version and the torch thread count.
``--resume`` continues a run only when the command gives the same; anything else is refused with a
message naming what differs and the command that would resume it. ``--extend-iterations N`` is the one
deliberate change: the run goes on to N iterations in total, and config.json lists each extension. The
command that started or extended a run finishes it: an interrupted extension resumes with the same
``--extend-iterations N``, and an extended run also resumes with the iteration count it was started with.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import shlex
import sys
from pathlib import Path
from typing import Any

import torch

from trioman import __version__
from trioman.runtime.formats import Subject, load_subject
from trioman.runtime.formats.avatar import sha256_file
from trioman.runtime.formats.subject import BODY_NPZ, FRAMES_NPZ, SUBJECT_JSON
from trioman.runtime.outputs import atomic_write_text
from trioman.runtime.options import declared, flags
from trioman.toolkit.train.augment_config import AugmentConfig
from trioman.toolkit.train.config import PRESETS, TrainConfig, with_subject_defaults

CONFIG_JSON = "config.json"
_SHOWN = 4  # differing config fields named in a refusal


def subject_sha256(subject: Subject) -> str:
    """sha256 over the subject's files: subject.json, body.npz, frames.npz and every frame's image and mask."""
    root = Path(subject.root)
    names = [SUBJECT_JSON, BODY_NPZ, FRAMES_NPZ]
    names += [str(p.relative_to(root)) for i in range(subject.num_frames) for p in (subject.image_path(i), subject.mask_path(i))]
    h = hashlib.sha256()
    for name in names:
        h.update(f"{name}\0{sha256_file(root / name)}\n".encode())
    return h.hexdigest()


def new_record(subject: Subject, cfg: TrainConfig) -> dict[str, Any]:
    """config.json of a fresh run (trained with deterministic kernels, toolkit/cpu.py)."""
    return {
        "trioman_version": __version__,
        "subject": str(Path(subject.root).resolve()),
        "subject_sha256": subject_sha256(subject),
        "subject_tool": subject.meta.get("generator", {}).get("tool"),  # what the subject-dependent defaults follow
        "extra_frames_sha256": None if cfg.extra_frames is None else subject_sha256(load_subject(cfg.extra_frames)),
        "config_hash": cfg.digest(),
        "threads": torch.get_num_threads(),
        "deterministic": True,
        "train": cfg.to_dict(),
        "extensions": [],
    }


def read_record(run: Path) -> dict[str, Any]:
    path = Path(run) / CONFIG_JSON
    try:
        record = json.loads(path.read_text(encoding="utf-8"))
        TrainConfig.from_dict(record["train"])
    except (ValueError, KeyError, TypeError) as err:
        raise ValueError(f"{path}: not a readable run record ({type(err).__name__}: {err})") from None
    return record


def write_record(run: Path, record: dict[str, Any]) -> None:
    """Write config.json (creating ``run``); a failed write (disk full) leaves no folder it created."""
    run = Path(run)
    fresh = not run.exists()
    run.mkdir(parents=True, exist_ok=True)
    try:
        atomic_write_text(run / CONFIG_JSON, json.dumps(record, indent=2) + "\n")
    except BaseException:
        if fresh:
            run.rmdir()
        raise


def _flat(d: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in d.items():
        if isinstance(v, dict):
            out.update(_flat(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = list(v) if isinstance(v, tuple) else v
    return out


def config_differences(old: TrainConfig, new: TrainConfig) -> list[str]:
    """'field: old -> new' for every config field that differs (nested fields dotted)."""
    a, b = _flat(old.to_dict()), _flat(new.to_dict())
    return [f"{k}: {a.get(k)!r} -> {b.get(k)!r}" for k in sorted(set(a) | set(b)) if a.get(k) != b.get(k)]


def _words(saved: Any, default: Any, names: list[str], always: tuple[str, ...] = ()) -> list[str]:
    """The flags (trioman/options.py) that give ``saved``'s fields ``names`` where they differ from ``default``'s
    (``always``: whenever set)."""
    flag = flags(type(saved))
    words: list[str] = []
    for name in names:
        value = getattr(saved, name)
        if value is None or (name not in always and value == getattr(default, name)):
            continue
        if isinstance(value, bool):
            words.append(flag[name] if value else "--no-" + flag[name][2:])
        else:
            words += [flag[name], str(value)]
    return words


def resume_command(run: Path, record: dict[str, Any], extend_to: int | None = None) -> str:
    """The ``trioman train`` command that resumes the run (its subject, preset and flags from config.json;
    ``--extend-iterations`` when the run was extended, or ``extend_to``)."""
    saved = TrainConfig.from_dict(record["train"])
    extensions = record.get("extensions") or []
    first = extensions[0]["iterations_before"] if extensions else saved.iterations
    # the preset's defaults as the run's subject resolved them (a record without the subject's tool predates them)
    base = with_subject_defaults(dataclasses.replace(PRESETS.get(saved.preset, TrainConfig()), augment=saved.augment),
                                 record.get("subject_tool"))
    words = ["trioman", "train", str(record.get("subject", "SUBJECT")), "--out", str(run)]
    if saved.preset != "quick":
        words += ["--preset", saved.preset]
    if first != base.iterations:
        words += ["--iterations", str(first)]
    words += _words(saved, base, ["image_scale", "seed", "extra_frames", "extra_weight", "refine_poses"])
    if saved.augment is not None:
        aug = saved.augment
        words += ["--augment", aug.mode]
        default = AugmentConfig(mode=aug.mode, refiner=aug.refiner, examiner=aug.examiner)
        words += _words(aug, default, [f.name for f, _ in declared(AugmentConfig) if f.name != "mode"],
                        always=("refiner", "examiner"))
    words.append("--resume")
    target = extend_to if extend_to is not None else (saved.iterations if extensions else None)
    if target is not None:
        words += ["--extend-iterations", str(target)]
    return shlex.join(words)


def check_resume(run: Path, record: dict[str, Any], subject: Subject, cfg: TrainConfig, step: int,
                 extend_iterations: int | None) -> tuple[TrainConfig, dict[str, Any]]:
    """Refuse to resume the run whose config.json is ``record`` with another subject, config or code version
    (ValueError naming what differs and the command that would resume it). -> the run's config and its
    record, extended to ``extend_iterations`` when given (``step``: the step of the checkpoint the run resumes
    from). The same ``extend_iterations`` as the run's last extension continues that extension; without it,
    the iteration count the run was started with (or any it was extended from) resumes it as recorded."""
    where = f"resume: {Path(run) / CONFIG_JSON}"
    if record.get("trioman_version") != __version__:
        raise ValueError(f"{where}: the run was made by trioman {record.get('trioman_version')}, this is trioman "
                         f"{__version__}; resume it with that version, or start a new run")
    path = str(Path(subject.root).resolve())
    if record.get("subject") != path:
        raise ValueError(f"{where}: the run trains on the subject {record.get('subject')}, not {path}; resume it "
                         f"with `{resume_command(run, record)}`")
    if "subject_sha256" in record and record["subject_sha256"] != subject_sha256(subject):
        raise ValueError(f"{where}: the subject {path} changed since the run started (its files' hash differs from "
                         f"the recorded {record['subject_sha256'][:12]}); start a new run")
    saved = TrainConfig.from_dict(record["train"])
    extensions = record.get("extensions") or []
    earlier = {saved.iterations, *(e.get("iterations_before") for e in extensions)}
    same_count = extend_iterations is not None or cfg.iterations in earlier
    given = dataclasses.replace(cfg, iterations=saved.iterations) if same_count else cfg
    # Avatar fields come from the preset, not from flags: one the run's record lacks (added to the code later)
    # is the run's own, its default, which reproduces the run's avatar.
    later = [f.name for f in dataclasses.fields(saved.avatar) if f.name not in record["train"].get("avatar", {})]
    if later:
        given = dataclasses.replace(given, avatar=dataclasses.replace(
            given.avatar, **{name: getattr(saved.avatar, name) for name in later}))
    diff = config_differences(saved, given)
    if diff:
        more = f" and {len(diff) - _SHOWN} more" if len(diff) > _SHOWN else ""
        raise ValueError(f"{where}: the training config differs from the run's ({'; '.join(diff[:_SHOWN])}{more}); "
                         f"resume with the options the run was started with: `{resume_command(run, record)}` (or "
                         f"`extend_iterations` N to continue it to N iterations)")
    if saved.extra_frames is not None and record.get("extra_frames_sha256") not in (
            None, subject_sha256(load_subject(saved.extra_frames))):
        raise ValueError(f"{where}: the extra frames {saved.extra_frames} changed since the run started; start a new run")
    threads = record.get("threads")
    if threads is not None and threads != torch.get_num_threads():
        print(f"train: note: {Path(run)} was trained with {threads} torch threads, this process has "
              f"{torch.get_num_threads()}: the weights will not match an uninterrupted run bit for bit "
              f"(OMP_NUM_THREADS={threads} gives the recorded count)", file=sys.stderr)
    if extend_iterations is None:
        if cfg.iterations != saved.iterations:
            print(f"train: note: {Path(run)} was extended to {saved.iterations} iterations (config.json); resuming "
                  f"to {saved.iterations}", file=sys.stderr)
        return saved, record
    if extensions and extend_iterations == saved.iterations == extensions[-1].get("iterations"):
        return saved, record  # the same extension, interrupted: it goes on
    if extend_iterations <= saved.iterations:
        hint = (f"resume it with `{resume_command(run, record)}`, or extend it further with `extend_iterations` N, "
                f"N > {saved.iterations}")
        raise ValueError(f"extend_iterations: {extend_iterations} is not more than the run's {saved.iterations} "
                         f"iterations; {hint}")
    extended = dataclasses.replace(saved, iterations=extend_iterations)
    extension = {"from_step": step, "iterations_before": saved.iterations, "iterations": extend_iterations,
                 "trioman_version": __version__}
    record = dict(record, config_hash=extended.digest(), train=extended.to_dict(),
                  extensions=[*record.get("extensions", []), extension])
    return extended, record
