"""``trioman export pretrained ONNX_DIR``: the fp32 Refiner and Examiner of a ``trioman export onnx`` folder become
the models the package ships (runtime/pretrained.py reads them; the model card is docs/models.md).

``make models`` runs the whole recipe (corpus, training, export, this step). The record keeps what a reader needs
to trust the files (bytes, sha256, input size, parity against torch, the training step and config) and no
machine's paths.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from trioman.runtime import pretrained as rt
from trioman.runtime.formats.avatar import sha256_file
from trioman.runtime.formats.common import FormatError, read_json
from trioman.runtime.onnx_models import ALIGNED_CONDITIONS
from trioman.runtime.outputs import atomic_path

MAX_BYTES = 25 * 10**6  # both models together: what a pip package may carry
EXPORT_JSON = "export.json"


def _entry(report: dict, kind: str, where: Path) -> dict[str, Any]:
    file = report.get("files", {}).get(f"{kind}.onnx")
    model = report.get("models", {}).get(kind)
    if not isinstance(file, dict) or not isinstance(model, dict) or file.get("precision") != "fp32":
        raise FormatError(f"{where}: files.{kind}.onnx: no fp32 {kind} was written (export it with "
                          f"`trioman export onnx --{kind} RUN --variants fp32`)")
    if file.get("external_data"):
        raise FormatError(f"{where}: files.{kind}.onnx: its weights lie in an external file; a shipped model is one file")
    parity = file.get("parity") or {}
    return {"file": f"{kind}.onnx", "bytes": file["bytes"], "sha256": file["sha256"], "precision": "fp32",
            "input_size": file["input_size"], "parity_max_abs": file["parity_max_abs"],
            "parity_frames": parity.get("frames_source"), "step": model.get("step"), "config_hash": model.get("config_hash"),
            "config": model.get("config"), **({"conditions": model["conditions"]} if "conditions" in model else {})}


def heldout_quality(onnx_dir: Path, triplets: Sequence[str | os.PathLike], batch: int = 8) -> dict[str, Any]:
    """The ONNX files of ``onnx_dir`` under onnxruntime on the test frames of held-out subjects' triplet files:
    masked PSNR (white background) of the coarse render and of the refined frame against the real one (and, for a
    Refiner of the "warp*" conditions, of its aligned input: what the aligned kind trains on, the bar the Refiner
    must clear), and the Examiner's AUROC of real against coarse frames with the nearest-view training frame as
    reference."""
    import torch

    from trioman.runtime.onnx_models import load_model
    from trioman.toolkit.examiner import auroc
    from trioman.toolkit.metrics import evaluate_batch
    from trioman.toolkit.corpus.training import nchw
    from trioman.toolkit.corpus.triplets import TripletSet

    t = TripletSet.load(list(triplets)).evaluation("test")
    refiner, examiner = load_model(onnx_dir / "refiner.onnx", kind="refiner"), load_model(onnx_dir / "examiner.onnx", kind="examiner")
    aligned_in = refiner.conditions in ALIGNED_CONDITIONS
    ref_in = t.aligned if aligned_in else t.reference
    refined = np.concatenate([refiner.refine(t.coarse[i:i + batch], reference=ref_in[i:i + batch], normal=t.normal[i:i + batch])
                              for i in range(0, len(t.gt), batch)])
    mask = torch.from_numpy(np.ascontiguousarray(t.mask[:, None]))
    psnr = {name: float(evaluate_batch(nchw(x), nchw(t.gt), mask)["psnr"].mean()) for name, x in
            (("render", t.coarse), ("refined", refined)) + ((("aligned", t.aligned),) if aligned_in else ())}
    scores = [np.concatenate([examiner.score(x[i:i + 1], t.reference[i]) for i in range(len(x))]) for x in (t.gt, t.coarse)]
    labels = np.r_[np.ones(len(t.gt)), np.zeros(len(t.gt))]
    out = {"test_frames": len(t.gt), "subjects": [Path(p).stem for p in triplets],
           "psnr_render_db": round(psnr["render"], 3), "psnr_refined_db": round(psnr["refined"], 3),
           "refiner_gain_db": round(psnr["refined"] - psnr["render"], 3)}
    if aligned_in:
        out.update(psnr_aligned_db=round(psnr["aligned"], 3), refiner_gain_over_aligned_db=round(psnr["refined"] - psnr["aligned"], 3))
    return {**out, "examiner_auroc_real_vs_render": round(float(auroc(np.concatenate(scores), labels)), 4)}


def ship_pretrained(onnx_dir: str | os.PathLike, dest: str | os.PathLike = rt.PRETRAINED_DIR,
                    recipe: str = "make models (Makefile; docs/models.md)",
                    heldout: Sequence[str | os.PathLike] = ()) -> dict[str, Any]:
    """Copy ``onnx_dir``'s fp32 ``refiner.onnx`` and ``examiner.onnx`` into ``dest`` and write ``models.json``
    (runtime/pretrained.py's record). -> the record. Each file is checked against export.json's sha256 first; the
    two together must stay within MAX_BYTES. With ``heldout`` triplet files (subjects the models never saw), the
    record holds the files' quality on them (``heldout_quality``)."""
    onnx_dir, dest = Path(onnx_dir), Path(dest)
    where = onnx_dir / EXPORT_JSON
    report = read_json(where)
    if not isinstance(report, dict):
        raise FormatError(f"{where}: expected an object (trioman export onnx's report)")
    models = {kind: _entry(report, kind, where) for kind in rt.KINDS}
    for entry in models.values():
        src = onnx_dir / entry["file"]
        if not src.is_file() or sha256_file(src) != entry["sha256"]:
            raise FormatError(f"{src}: missing or not the file {where} records (sha256 differs)")
    total = sum(e["bytes"] for e in models.values())
    if total > MAX_BYTES:
        raise ValueError(f"onnx_dir: {onnx_dir}'s models take {total / 1e6:.1f} MB together, over the "
                         f"{MAX_BYTES / 1e6:.0f} MB a shipped package may carry")
    if not dest.is_dir():
        raise FileNotFoundError(f"dest: {dest} is not a folder")
    record = {"format": rt.FORMAT, "format_version": rt.FORMAT_VERSION, "recipe": recipe, "card": "docs/models.md",
              "exported_by": {k: report.get(k) for k in ("trioman_version", "opset", "exporter", "torch", "onnx",
                                                         "onnxruntime", "tolerances")},
              "models": models}
    if heldout:
        record["heldout"] = heldout_quality(onnx_dir, heldout)
    for entry in models.values():
        with atomic_path(dest / entry["file"]) as tmp:
            shutil.copyfile(onnx_dir / entry["file"], tmp)
    with atomic_path(dest / rt.RECORD) as tmp:
        tmp.write_text(json.dumps(record, indent=2) + "\n")
    for kind in rt.KINDS:
        rt.shipped_path(kind, dest)  # reads back what was written
    return record
