"""The entry points: sizes, one model's or both models' export into a folder, and the summary lines."""

from __future__ import annotations

import json
import os
import shutil
import time
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np
import onnx
import torch

from trioman import __version__
from trioman.export.config import VARIANTS, OnnxExportOptions
from trioman.export.onnx_models.checkpoints import load_source
from trioman.export.onnx_models.constants import (
    EXAMINER_ATOL,
    EXPORT_FOLDER,
    EXPORT_JSON,
    EXPORTER,
    INT8_MAX_PSNR_DROP_DB,
    INT8_MIN_AGREEMENT,
    OPSET,
    REFINER_ATOL,
    REPORT_FORMAT,
)
from trioman.export.onnx_models.errors import ExportError
from trioman.export.onnx_models.frames import load_data, triplet_size
from trioman.export.onnx_models.graph import external_data_path
from trioman.export.onnx_models.jobs import ExaminerJob, Job, RefinerJob
from trioman.runtime.outputs import atomic_folder, check_folder_target, fsync_dir, temp_sibling, write_synced


def _square(size: int | Sequence[int] | None, name: str = "size") -> tuple[int, int] | None:
    if size is None:
        return None
    if isinstance(size, (int, np.integer)) and not isinstance(size, bool):
        hw = (int(size), int(size))
    else:
        hw = tuple(int(v) for v in size)
    if len(hw) != 2 or min(hw) < 1:
        raise ExportError(f"{name}: expected a positive integer or (H, W), got {size!r}")
    return hw


def refiner_export_size(config: Any, size: int | Sequence[int] | None, calibration: Sequence[str | os.PathLike] | None,
                        multiple: int | None = None) -> tuple[int, int]:
    """``size`` if given, else the calibration triplets' frame size, else ``config.image_size``; each side a
    multiple of ``multiple`` (the model's ``total_downsample``; default ``config.total_downsample``)."""
    hw = _square(size)
    origin = "size"
    if hw is None and calibration:
        hw, origin = triplet_size(calibration), "the calibration triplets' frame size"
    if hw is None:
        hw, origin = (config.image_size, config.image_size), "the Refiner's config.image_size"
    f = multiple or config.total_downsample
    if hw[0] % f or hw[1] % f:
        raise ExportError(f"size: (H, W) = {hw} ({origin}) is not a multiple of the Refiner's total downsampling {f}; "
                          f"give a `size` that is")
    return hw


def _job(kind: str, model_or_ckpt: Any, size: Any, calibration: Sequence[str | os.PathLike] | None, seed: int,
         calibration_frames: int, gate_frames: int, triplets: Any = None) -> Job:
    src = load_source(kind, model_or_ckpt)
    if kind == "refiner":
        hw = refiner_export_size(src.model.config, size, calibration, src.model.total_downsample)
    else:
        s = src.model.config.img_size
        hw = (s, s)
        if size is not None and _square(size) != hw:
            raise ExportError(f"size: the Examiner's input size is fixed by its config.img_size {s}, got {size!r}")
    data = load_data(calibration, hw, calibration_frames=calibration_frames, gate_frames=gate_frames, seed=seed,
                     triplets=triplets)
    return (RefinerJob if kind == "refiner" else ExaminerJob)(src, hw, data, seed)


def file_name(kind: str, precision: str) -> str:
    return f"{kind}.onnx" if precision == "fp32" else f"{kind}.{precision}.onnx"


def _check_variants(variants: Sequence[str] | str) -> tuple[str, ...]:
    if isinstance(variants, str):
        variants = [v.strip() for v in variants.split(",") if v.strip()]
    variants = tuple(dict.fromkeys(variants))
    unknown = [v for v in variants if v not in VARIANTS]
    if not variants or unknown:
        raise ExportError(f"variants: expected a non-empty subset of {VARIANTS}, got {list(variants)}")
    return variants


def _export_into(job: Job, folder: Path, variants: tuple[str, ...]) -> dict[str, dict]:
    """Write the model's variants into ``folder``; -> {file name: entry} (rejected ones included, not written)."""
    entries: dict[str, dict] = {}
    fp32 = folder / file_name(job.kind, "fp32")
    entry = job.export_fp32(fp32)
    if "fp32" in variants:
        entries[fp32.name] = entry
    for precision in ("int8", "fp16"):
        if precision not in variants:
            continue
        path = folder / file_name(job.kind, precision)
        entry = job.export_int8(fp32, path) if precision == "int8" else job.export_fp16(fp32, path)
        if entry["status"] != "written":
            path.unlink(missing_ok=True)
        entries[path.name] = entry
    if "fp32" not in variants:
        fp32.unlink()
        external_data_path(fp32).unlink(missing_ok=True)
    return entries


def _model_report(job: Job) -> dict:
    return {"source": job.src.source, "step": job.src.step, "config_hash": job.src.config_hash,
            "config": job.config.to_dict(), "input_size": list(job.size), "inputs": list(job.inputs),
            "outputs": list(job.outputs), "data": job.data.info,
            **({"conditions": job.config.conditions, "size_multiple": job.multiple} if job.kind == "refiner" else {})}


def _export_one(kind: str, model_or_ckpt: Any, path: str | os.PathLike, *, size: Any, precision: str,
                calibration: Sequence[str | os.PathLike] | None, seed: int, calibration_frames: int, gate_frames: int,
                overwrite: bool) -> dict:
    precision = _check_variants([precision])[0]
    path = Path(path)
    if path.exists() and not overwrite:
        raise FileExistsError(f"{path}: exists (pass overwrite=True to replace it)")
    if not path.parent.is_dir():
        raise FileNotFoundError(f"{path}: the folder {path.parent} does not exist")
    job = _job(kind, model_or_ckpt, size, calibration, seed, calibration_frames, gate_frames)
    tmp = temp_sibling(path)
    os.mkdir(tmp)
    try:
        entries = _export_into(job, tmp, (precision,))
        entry = entries[file_name(kind, precision)] | {"file": str(path), **_model_report(job)}
        if entry["status"] == "written":
            written = tmp / file_name(kind, precision)
            if external_data_path(written).is_file():  # its location is the bare name "<file name>.data"
                os.replace(external_data_path(written), path.with_name(external_data_path(written).name))
            os.replace(written, path)
            fsync_dir(path.parent)
        return entry
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def export_refiner_onnx(model_or_ckpt: Any, path: str | os.PathLike, *, size: int | Sequence[int] | None = None,
                        precision: str = "fp32", calibration: Sequence[str | os.PathLike] | None = None, seed: int = 0,
                        calibration_frames: int = 32, gate_frames: int = 32, overwrite: bool = False) -> dict:
    """Export a Refiner (module, checkpoint file or run folder) as one ONNX file of ``precision``.

    -> the file's report entry (parity, gate, bytes, sha256, seconds, source). An int8 model that
    fails its gate, or an fp16 one that yields NaN/Inf, is not written: ``entry["status"] == "REJECTED"``.
    fp32 parity beyond tolerance raises ExportParityError. Nothing is left behind on error.
    """
    return _export_one("refiner", model_or_ckpt, path, size=size, precision=precision, calibration=calibration, seed=seed,
                       calibration_frames=calibration_frames, gate_frames=gate_frames, overwrite=overwrite)


def export_examiner_onnx(model_or_ckpt: Any, path: str | os.PathLike, *, precision: str = "fp32",
                         calibration: Sequence[str | os.PathLike] | None = None, seed: int = 0, calibration_frames: int = 32,
                         gate_frames: int = 32, overwrite: bool = False) -> dict:
    """Export an Examiner (module, checkpoint file or run folder) as one ONNX file; see export_refiner_onnx.
    Its input size is its config's img_size."""
    return _export_one("examiner", model_or_ckpt, path, size=None, precision=precision, calibration=calibration, seed=seed,
                       calibration_frames=calibration_frames, gate_frames=gate_frames, overwrite=overwrite)


def export_onnx(refiner: Any = None, examiner: Any = None, out: str | os.PathLike | None = None, *,
                variants: Sequence[str] | str = OnnxExportOptions.variants,
                calibration: Sequence[str | os.PathLike] | None = OnnxExportOptions.calibration,
                size: int | Sequence[int] | None = OnnxExportOptions.size, overwrite: bool = False, seed: int = 0,
                calibration_frames: int = 32, gate_frames: int = 32,
                progress: Callable[[str], None] | None = None) -> dict:
    """``trioman export onnx``: the Refiner and/or the Examiner (modules, checkpoint files or run folders)
    -> an output folder of ONNX files + export.json; -> the report (what export.json holds).

    ``size`` is the Refiner's export size (int or (H, W)); the Examiner's is its config's. The folder
    is written as a temporary sibling renamed into place: an error (ExportParityError, ...) leaves
    nothing, and a non-empty ``out`` is replaced only with ``overwrite``.
    """
    if refiner is None and examiner is None:
        raise ExportError("refiner and examiner: both None, nothing to export; give a Refiner and/or an Examiner checkpoint")
    if out is None:
        raise ExportError("out: the output folder is required")
    variants = _check_variants(variants)
    out = Path(out)
    read = [x for x in (refiner, examiner, *(calibration or ())) if isinstance(x, (str, os.PathLike))]
    check_folder_target(out, overwrite, EXPORT_FOLDER, read)
    calibration = [Path(p) for p in calibration] if calibration else None
    for k, v in (("calibration_frames", calibration_frames), ("gate_frames", gate_frames)):
        if not isinstance(v, int) or isinstance(v, bool) or v < 1:
            raise ExportError(f"{k}: must be a positive integer, got {v!r}")
    say = progress or (lambda msg: None)
    t0 = time.perf_counter()
    import onnxruntime

    report: dict[str, Any] = {
        "format": REPORT_FORMAT, "version": 1, "trioman_version": __version__, "opset": OPSET, "exporter": EXPORTER,
        "torch": torch.__version__, "onnx": onnx.__version__, "onnxruntime": onnxruntime.__version__,
        "variants": list(variants), "models": {}, "files": {}, "rejected": {},
        "tolerances": {"refiner_fp32_atol": REFINER_ATOL, "examiner_fp32_atol": EXAMINER_ATOL,
                       "refiner_int8_max_psnr_drop_db": INT8_MAX_PSNR_DROP_DB,
                       "examiner_int8_min_agreement": INT8_MIN_AGREEMENT},
    }
    triplets = None
    if calibration:
        from trioman.toolkit.corpus.triplets import TripletSet

        say(f"reading {len(calibration)} triplet file(s)")
        triplets = TripletSet.load(calibration)
    with atomic_folder(out, overwrite, EXPORT_FOLDER) as tmp:
        for kind, what in (("refiner", refiner), ("examiner", examiner)):
            if what is None:
                continue
            say(f"{kind}: exporting {', '.join(variants)}")
            job = _job(kind, what, size if kind == "refiner" else None, calibration, seed, calibration_frames, gate_frames,
                       triplets)
            report["models"][kind] = _model_report(job)
            for name, entry in _export_into(job, tmp, variants).items():
                report["files" if entry["status"] == "written" else "rejected"][name] = entry
        report["seconds"] = round(time.perf_counter() - t0, 3)
        write_synced(tmp / EXPORT_JSON, (json.dumps(_finite(report), indent=2, allow_nan=False) + "\n").encode("utf-8"))
    report["out"] = str(out)
    return report


def _finite(obj: Any) -> Any:
    """``obj`` with NaN/Inf floats written as strings ("nan", "inf"), so the report stays strict JSON."""
    if isinstance(obj, float) and not np.isfinite(obj):
        return str(obj)
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite(v) for v in obj]
    return obj


def summary_lines(report: dict) -> list[str]:
    """One line per file (written or REJECTED) with size and parity/gate numbers, then export.json's path."""
    out = Path(report.get("out", "."))
    lines = []
    for name, e in list(report["files"].items()) + list(report["rejected"].items()):
        g = e.get("gate") or {}
        gate = ""
        if "psnr_drop" in g:
            gate = f", PSNR fp32 {g['fp32_psnr']:.2f} dB, int8 {g['int8_psnr']:.2f} dB (drop {g['psnr_drop']:+.3f}, max {g['max_drop']})"
        elif "agreement" in g:
            gate = f", decisions agree {100 * g['agreement']:.1f}% with fp32 (min {100 * g['min_agreement']:.0f}%)"
        parity = "" if e["parity_max_abs"] is None else f"max |onnx - torch| {e['parity_max_abs']:.2g}"
        if e["precision"] == "fp32":
            parity += f" (atol {e['parity']['atol']:g})"
        note = "; GPU artifact, no speed on CPU" if e["precision"] == "fp16" else ""
        if e["status"] == "written":
            lines.append(f"export: {out / name}  ({e['bytes'] / 1e6:.2f} MB, {parity}{gate}{note})")
        else:
            lines.append(f"export: REJECTED {name}: not written ({parity}{gate})")
    for kind, model in report.get("models", {}).items():
        if model.get("data", {}).get("source") == "synthetic":
            lines.append(f"export: note: {kind}: {model['data']['note']}")
    lines.append(f"export: report {out / EXPORT_JSON}")
    return lines
