"""``trioman export onnx``: the Refiner and the Examiner as ONNX files for the torch-free runtime.

    export_onnx(refiner=CKPT, examiner=CKPT, out=DIR, variants=("fp32", "int8", "fp16"), calibration=[npz, ...])

writes, into a temporary sibling folder renamed onto ``out`` at the end (an error leaves nothing):

    refiner.onnx / examiner.onnx              fp32, traced with batch 2, symbolic batch axis "batch", opset 17
    refiner.int8.onnx                         static QDQ, per-channel QInt8 weights, QUInt8 activations
    examiner.int8.onnx                        dynamic int8 of the weight MatMul/Gemm (never Conv: ConvInteger
                                              has no CPU kernel)
    refiner.fp16.onnx / examiner.fp16.onnx    fp16 weights and maths, fp32 I/O; a GPU artifact (no speed on CPU)
    export.json                               per file: precision, bytes, sha256, parity vs torch, gates, seconds

Every file carries the ``trioman.*`` metadata that ``trioman.runtime.models`` requires (docs/formats.md,
"ONNX models"). Checks, in order (docs/design.md, "Deployment (ONNX)"):

- the exported dims: dim 0 of every input and of the output symbolic, the rest static (= the input size);
- ``onnx.checker.check_model(full_check=True)``;
- fp32 parity, torch vs onnxruntime (through the runtime's own loader) at batch 1 and 3 on random
  inputs and on real triplet frames when calibration data is given: Refiner image atol 1e-3, Examiner
  score atol 1e-4. Beyond it -> ``ExportParityError`` and nothing is written;
- int8 task gates on held-out frames (the triplets' test split when there is one): the Refiner's
  refined-vs-GT PSNR within 0.3 dB of fp32's, the Examiner's keep/drop decisions (choice between the
  coarse render and the real frame; score >= 0.5) agreeing with fp32's on >= 98%. A variant that fails
  is not written and is reported as REJECTED with its numbers;
- fp16: parity vs torch recorded (no gate; rejected only if it produces NaN/Inf).

The traced Refiner is an exportable copy whose GroupNorms subtract each group's mean first (the same
function; onnxruntime's InstanceNormalization kernel, which the GroupNorm export goes through, computes
the variance in one pass and loses precision on uncentred groups).

Sizes: the Refiner is convolutional and trained on crops, so its export size is ``size`` if given,
else the calibration triplets' frame size, else its config's ``image_size`` (a multiple of its total
downsampling). The Examiner's size is its config's ``img_size``; calibration frames of another size
are resized with cv2.INTER_AREA (as ``ExaminerModel.score`` does).
"""

from __future__ import annotations

import abc

import contextlib
import hashlib
import io
import json
import os
import shutil
import tempfile
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, NamedTuple, Sequence

import numpy as np
import onnx
import torch
from torch import nn

from trioman import __version__
from trioman.runtime import models as rt
from trioman.runtime.formats.avatar import sha256_file
from trioman.runtime.image_io import (
    FolderKind,
    atomic_folder,
    check_folder_target,
    fsync_dir,
    fsync_file,
    temp_sibling,
    write_synced,
)
from trioman.runtime.metrics import psnr

OPSET = 17
EXPORTER = "torch.onnx.export, TorchScript (legacy) exporter, dynamo=False"
TRACE_BATCH = 2  # trace with batch >= 2 (a traced size-1 batch may be specialised)
PARITY_BATCHES = (1, 3)  # other batch sizes than the traced one
BATCH_AXIS = "batch"
MAX_PROTO_BYTES = 2**31 - 2**24  # one serialised ONNX protobuf is below 2 GiB; keep 16 MiB for the graph itself
REFINER_ATOL = 1e-3  # max |onnxruntime - torch| on refined images (docs/design.md, Deployment)
EXAMINER_ATOL = 1e-4  # on Examiner scores
INT8_MAX_PSNR_DROP_DB = 0.3  # Refiner int8 gate: refined-vs-GT PSNR within this of fp32's
INT8_MIN_AGREEMENT = 0.98  # Examiner int8 gate: keep/drop decisions agreeing with fp32's
KEEP_THRESHOLD = 0.5  # the Examiner decision threshold the gate checks
VARIANT_PARITY_FRAMES = 8  # int8/fp16 parity with torch (informative, not gated) on this many gate frames
# Refiner frames per batch when the export runs it on frames (calibration, parity, gate): at most
# REFINER_BATCH_PIXELS pixels per image and at most REFINER_MAX_BATCH frames. Its activations grow with
# the pixels of a batch (its cross-view attention with their square per frame); onnxruntime's outputs
# do not depend on the batch, so neither do the calibration ranges nor the gates.
REFINER_BATCH_PIXELS = 256 * 256
REFINER_MAX_BATCH = 8
VARIANTS = ("fp32", "int8", "fp16")
# Refiner int8: the ops with weights (and the attention MatMuls) only; quantizing every op buys no
# accuracy (docs/findings.md, "ONNX export").
REFINER_INT8_OPS = ("Conv", "MatMul", "Gemm")
EXPORT_JSON = "export.json"
# What --overwrite may replace (image_io.check_folder_target): an export folder of exactly these files.
EXPORT_FOLDER = FolderKind("ONNX export", EXPORT_JSON, files=(EXPORT_JSON, "refiner*.onnx", "examiner*.onnx",
                                                              "refiner*.onnx.data", "examiner*.onnx.data"))
REPORT_FORMAT = "trioman-onnx-export"
# fp16: ops kept in fp32 on top of onnxruntime's default block list (overflow-prone reductions and
# normalisations: LayerNorm/GroupNorm squares, softmax exponentials; Resize as the reference suggests).
FP16_KEEP_FP32 = ("LayerNormalization", "GroupNormalization", "InstanceNormalization", "Softmax", "ReduceMean",
                  "ReduceSum", "Pow", "Sqrt", "Resize", "Log", "Exp")
FP32_NOTE = "reference precision, checked against torch"
FP16_NOTE = "GPU artifact: fp16 brings no speed on onnxruntime's CPU execution provider (it inserts casts)"


class ExportError(ValueError):
    """An export that cannot be made as asked, or whose graph is not what the runtime expects."""


class ExportParityError(ExportError):
    """The fp32 ONNX model differs from the torch model beyond the tolerance (nothing was written)."""


# --------------------------------------------------------------------------------------------------
# models and checkpoints


def resolve_checkpoint(ckpt: str | os.PathLike) -> Path:
    """A checkpoint file itself, or a run folder's model checkpoint (its validation-selected
    weights, run/selected.pt, if it has them, else its latest checkpoint)."""
    from trioman.toolkit.train.checkpoint import model_checkpoint

    path = Path(ckpt)
    if path.is_dir():
        found = model_checkpoint(path)
        if found is None:
            raise FileNotFoundError(f"{path}: run folder without a checkpoint (no checkpoints/ckpt_*.pt)")
        return found
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such checkpoint file or run folder")
    return path


def config_hash(model_config: dict, train_config: dict | None) -> str:
    """sha256 hex of {"model": model config, "train": training config} as JSON with sorted keys."""
    text = json.dumps({"model": model_config, "train": train_config}, sort_keys=True, default=str)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


class _CenteredGroupNorm(nn.GroupNorm):
    """GroupNorm that subtracts each group's mean before normalising: the same function, but exported as
    ReduceMean + Sub before ONNX InstanceNormalization, whose onnxruntime CPU kernel computes the variance
    in one pass (E[x^2] - E[x]^2) and loses precision when a group's mean is large against its spread
    (docs/findings.md, "ONNX export")."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        g = x.reshape(x.shape[0], self.num_groups, -1)
        x = (g - g.mean(dim=-1, keepdim=True)).reshape(x.shape)
        return nn.functional.group_norm(x, self.num_groups, self.weight, self.bias, self.eps)


def _center_group_norms(model: nn.Module) -> nn.Module:
    for m in model.modules():
        if type(m) is nn.GroupNorm:
            m.__class__ = _CenteredGroupNorm
    return model


class _Source(NamedTuple):
    model: nn.Module  # exportable, eval mode
    source: str
    step: int | None
    config_hash: str


def _load(kind: str, model_or_ckpt: Any) -> _Source:
    """An exportable copy of the model (or the checkpoint's model) and where it came from."""
    from trioman.toolkit.examiner import Examiner, ExaminerConfig
    from trioman.toolkit.refiner import RefinerConfig, create_refiner

    def build(config: Any) -> nn.Module:
        with torch.random.fork_rng(devices=[]):  # initial weights are overwritten; keep the global RNG
            if kind == "refiner":
                return _center_group_norms(create_refiner(config, exportable=True, seed=0))
            return Examiner(config, exportable=True)

    if isinstance(model_or_ckpt, nn.Module):
        config = getattr(model_or_ckpt, "config", None)
        want = RefinerConfig if kind == "refiner" else ExaminerConfig
        if not isinstance(config, want):
            raise ExportError(f"{kind}: expected a {kind.capitalize()} module (with a {want.__name__} .config), "
                              f"got {type(model_or_ckpt).__name__}")
        model = build(config)
        model.load_state_dict(model_or_ckpt.state_dict())
        return _Source(model.eval(), f"<in-memory {type(model_or_ckpt).__name__}>", None, config_hash(config.to_dict(), None))
    from trioman.toolkit.train.checkpoint import load_checkpoint

    path = resolve_checkpoint(model_or_ckpt)
    state = load_checkpoint(path)
    try:
        config = (RefinerConfig if kind == "refiner" else ExaminerConfig).from_dict(state["config"])
    except (TypeError, ValueError) as err:
        raise ExportError(f"{path}: not a {kind} checkpoint ({err})") from None
    model = build(config)
    try:
        model.load_state_dict(state["model"])
    except RuntimeError as err:
        raise ExportError(f"{path}: weights do not fit a {kind} of its config ({str(err).splitlines()[0]})") from None
    return _Source(model.eval(), str(path.resolve()), int(state["step"]), config_hash(state["config"], state.get("train")))


# --------------------------------------------------------------------------------------------------
# frames: calibration and gate data


class Frames(NamedTuple):
    """Float32 NHWC images in [0, 1] at the export size."""

    gt: np.ndarray  # I^T
    coarse: np.ndarray  # I_c^T
    normal: np.ndarray  # I_g^T
    reference: np.ndarray  # I^{T+k} (calibration) / the nearest-view training frame (gate)

    @property
    def count(self) -> int:
        return len(self.gt)


def _resize(images: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    if tuple(images.shape[1:3]) == tuple(size):
        return np.ascontiguousarray(images, dtype=np.float32)
    import cv2

    H, W = size
    return np.stack([cv2.resize(np.ascontiguousarray(im, dtype=np.float32), (W, H), interpolation=cv2.INTER_AREA)
                     for im in images])


def _frames_at(t: Any, size: tuple[int, int]) -> Frames:
    return Frames(_resize(t.gt, size), _resize(t.coarse, size), _resize(t.normal, size), _resize(t.reference, size))


def synthetic_frames(n: int, size: tuple[int, int], seed: int) -> Frames:
    """Random stand-ins for triplet frames: smooth colour textures (gt), a blurred, colour-shifted, noisy
    copy (coarse), a shifted copy (reference) and another texture (normal)."""
    import cv2

    rng = np.random.default_rng(seed)
    H, W = size

    def texture() -> np.ndarray:
        low = rng.random((max(2, H // 8), max(2, W // 8), 3), dtype=np.float32)
        return np.clip(cv2.resize(low, (W, H), interpolation=cv2.INTER_LINEAR), 0, 1)

    gt = np.stack([texture() for _ in range(n)])
    coarse = np.stack([cv2.blur(g, (5, 5)) for g in gt]) + 0.15 * (rng.random((n, 1, 1, 3), dtype=np.float32) - 0.5)
    coarse = np.clip(coarse + 0.03 * rng.standard_normal(gt.shape, dtype=np.float32), 0, 1)
    reference = np.roll(gt, (2, 2), axis=(1, 2))
    normal = np.stack([texture() for _ in range(n)])
    return Frames(gt.astype(np.float32), coarse.astype(np.float32), normal, reference.astype(np.float32))


@dataclass
class Data:
    """Calibration and gate frames at one size, and how they were obtained (for the report)."""

    calibration: Frames
    gate: Frames
    info: dict


def load_data(calibration: Sequence[str | os.PathLike] | None, size: tuple[int, int], *, calibration_frames: int = 32,
              gate_frames: int = 32, seed: int = 0, triplets: Any = None) -> Data:
    """Calibration frames (T, T+k pairs of the training split) and gate frames (the test split with
    nearest-view references when there is one, else other random frames) from triplet files, resized to
    ``size``; synthetic random frames when ``calibration`` is None or empty. ``triplets``: the files
    already loaded as a TripletSet (to load them once for both models)."""
    if not calibration:
        return Data(synthetic_frames(calibration_frames, size, seed), synthetic_frames(gate_frames, size, seed + 1),
                    {"source": "synthetic", "note": "no calibration triplets given: int8 calibration and gates used "
                     "synthetic random images, not real frames", "calibration_frames": calibration_frames,
                     "gate_frames": gate_frames})
    from trioman.toolkit.triplets import TripletSet

    paths = [str(Path(p)) for p in calibration]
    data = triplets if triplets is not None else TripletSet.load(paths)
    rng = np.random.default_rng(seed)
    has_train, has_test = bool(np.any(data.split == "train")), bool(np.any(data.split == "test"))
    calib = data.sample(rng, calibration_frames, k_max=4, split="train" if has_train else None)
    if has_train and has_test:
        test = np.nonzero(data.split == "test")[0]
        pick = test[np.unique(np.linspace(0, len(test) - 1, min(gate_frames, len(test))).round().astype(int))]
        gate = data.take(pick, np.array([data.nearest_view(int(i)) for i in pick], dtype=np.int64))
        gate_split = "test"
    else:
        gate = data.sample(rng, gate_frames, k_max=4)
        gate_split = "all (no train/test split)"
    H0, W0 = data.gt.shape[1:3]
    return Data(_frames_at(calib, size), _frames_at(gate, size),
                {"source": "triplets", "files": paths, "frame_size": [int(H0), int(W0)],
                 "resized_to": list(size) if (H0, W0) != tuple(size) else None,
                 "calibration_frames": len(calib.gt), "calibration_split": "train" if has_train else "all",
                 "gate_frames": len(gate.gt), "gate_split": gate_split})


def triplet_size(calibration: Sequence[str | os.PathLike]) -> tuple[int, int]:
    """(H, W) of the first triplet file's frames, from its ``meta`` entry (the images are not read)."""
    from trioman.runtime.formats.common import FormatError

    path = Path(calibration[0])
    try:
        with np.load(path, allow_pickle=False) as archive:
            meta = json.loads(str(archive["meta"]))
        return int(meta["height"]), int(meta["width"])
    except FileNotFoundError:
        raise FormatError(f"{path}: missing file") from None
    except Exception as err:  # not an npz, no meta, malformed JSON, ...
        raise FormatError(f"{path}: not a triplet file with a 'meta' entry giving height and width "
                          f"({type(err).__name__}: {err})") from None


def _nchw(x: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(x.transpose(0, 3, 1, 2), dtype=np.float32)


# --------------------------------------------------------------------------------------------------
# the ONNX graph


def _dims(value_info: Any) -> list[int | str | None]:
    out = []
    for d in value_info.type.tensor_type.shape.dim:
        out.append(d.dim_value if d.HasField("dim_value") else (d.dim_param or None))
    return out


def check_dims(proto: onnx.ModelProto, inputs: Sequence[str], outputs: Sequence[str], input_tail: Sequence[int],
               output_tail: Sequence[int], where: str) -> None:
    """Input and output names, dim 0 symbolic ("batch"), the other dims static and as expected."""
    got_in = [i.name for i in proto.graph.input]
    got_out = [o.name for o in proto.graph.output]
    if got_in != list(inputs) or got_out != list(outputs):
        raise ExportError(f"{where}: graph inputs/outputs {got_in} / {got_out}, expected {list(inputs)} / {list(outputs)}")
    for v, tail in [(i, input_tail) for i in proto.graph.input] + [(o, output_tail) for o in proto.graph.output]:
        dims = _dims(v)
        if len(dims) != 1 + len(tail) or isinstance(dims[0], int) or dims[0] is None or list(dims[1:]) != list(tail):
            raise ExportError(f"{where}: {v.name!r} exported with dims {dims}, expected [{BATCH_AXIS!r}, "
                              f"{', '.join(map(str, tail))}] (symbolic batch, static rest)")


def pin_output_dims(proto: onnx.ModelProto) -> None:
    """Make the outputs' non-batch dims static where ONNX shape inference proves them (the legacy exporter
    declares every output dim of a dynamic-axes graph symbolic, e.g. 'Transposerefined_dim_1')."""
    inferred = onnx.shape_inference.infer_shapes(proto, strict_mode=True, data_prop=True)
    shapes = {o.name: o.type.tensor_type.shape.dim for o in inferred.graph.output}
    for o in proto.graph.output:
        for j, d in enumerate(o.type.tensor_type.shape.dim):
            if j == 0 or d.HasField("dim_value"):
                continue
            got = shapes.get(o.name)
            if got is not None and j < len(got) and got[j].HasField("dim_value"):
                d.dim_value = got[j].dim_value  # clears dim_param (a oneof)


def sort_nodes(proto: onnx.ModelProto) -> None:
    """Order the main graph's nodes topologically (onnxruntime's fp16 converter appends its input casts
    at the end, which onnxruntime accepts but the ONNX checker does not)."""
    nodes = list(proto.graph.node)
    producer = {out: i for i, n in enumerate(nodes) for out in n.output if out}
    done: set[int] = set()
    order: list[int] = []
    for start in range(len(nodes)):
        stack = [(start, False)]
        while stack:
            i, expanded = stack.pop()
            if i in done:
                continue
            if expanded:
                done.add(i)
                order.append(i)
                continue
            stack.append((i, True))
            stack.extend((producer[x], False) for x in nodes[i].input if x in producer and producer[x] not in done)
    if order != list(range(len(nodes))):
        del proto.graph.node[:]
        proto.graph.node.extend(nodes[i] for i in order)


def set_metadata(proto: onnx.ModelProto, meta: dict[str, str]) -> None:
    """Replace the model's ``trioman.*`` metadata_props by ``meta`` (keys with the prefix)."""
    keep = [(p.key, p.value) for p in proto.metadata_props if not p.key.startswith(rt.META_PREFIX)]
    del proto.metadata_props[:]
    for key, value in keep + sorted(meta.items()):
        entry = proto.metadata_props.add()
        entry.key, entry.value = key, str(value)


def _torch_export(model: nn.Module, example: tuple[torch.Tensor, ...], inputs: Sequence[str],
                  outputs: Sequence[str], scratch: Path | None = None) -> onnx.ModelProto:
    """The traced graph; with ``scratch`` (a folder), traced into a file there (the exporter then writes a
    model over 2 GiB as external data) and read back with its weights, for ``_save(..., external=True)``."""
    target: Any = io.BytesIO() if scratch is None else str(scratch / "trace.onnx")
    # no autograd: the trace would keep every activation for a backward pass (the same graph either way)
    with warnings.catch_warnings(), torch.no_grad():
        warnings.simplefilter("ignore")  # the legacy exporter's deprecation notice and tracer warnings
        torch.onnx.export(
            model, example, target, input_names=list(inputs), output_names=list(outputs), opset_version=OPSET,
            dynamic_axes={n: {0: BATCH_AXIS} for n in list(inputs) + list(outputs)}, dynamo=False,
        )
    return onnx.load_from_string(target.getvalue()) if scratch is None else onnx.load(target)


def external_data_path(path: Path) -> Path:
    """The weights file beside a model saved with external data: ``<name>.onnx.data``."""
    return path.with_name(path.name + ".data")


def _save(proto: onnx.ModelProto, path: Path, external: bool = False) -> None:
    """Write ``proto``; ``external`` puts every tensor over 1 KiB into ``external_data_path(path)`` (one file,
    read by onnxruntime from the same folder), for models over protobuf's 2 GiB."""
    if external:
        onnx.save_model(proto, str(path), save_as_external_data=True, all_tensors_to_one_file=True,
                        location=external_data_path(path).name, size_threshold=1024)
        for p in (path, external_data_path(path)):
            fsync_file(p)
    else:
        write_synced(path, proto.SerializeToString())


# --------------------------------------------------------------------------------------------------
# one model


class _Job(abc.ABC):
    """What the exports of one model share: the torch model, its size, names, metadata and data."""

    kind = ""
    atol = 0.0

    def __init__(self, src: _Source, size: tuple[int, int], data: Data, seed: int) -> None:
        self.src, self.model, self.size, self.data, self.seed = src, src.model, size, data, seed
        self.config = self.model.config
        self.inputs: tuple[str, ...] = ()
        self.outputs: tuple[str, ...] = ()

    # subclasses: names, output dims, metadata extras, real-frame feeds, gate
    @abc.abstractmethod
    def output_tail(self) -> tuple[int, ...]:
        """The output's dimensions after the batch."""

    def extra_meta(self) -> dict[str, str]:
        return {}

    @abc.abstractmethod
    def real_feeds(self, frames: Frames) -> list[dict[str, np.ndarray]]:
        """The graph's inputs built from real frames, one feed per batch."""

    @abc.abstractmethod
    def gate(self, fp32: Path, variant: Path) -> dict:
        """The task metric of a reduced-precision variant against the fp32 graph (its keep/drop verdict)."""

    def metadata(self, precision: str, extra: dict[str, str] | None = None) -> dict[str, str]:
        p = rt.META_PREFIX
        meta = {
            p + "format": rt.FORMAT,
            p + "format_version": rt.FORMAT_VERSION,
            p + "kind": self.kind,
            p + "precision": precision,
            p + "input_size": f"{self.size[0]},{self.size[1]}",
            p + "inputs": json.dumps(list(self.inputs)),
            p + "outputs": json.dumps(list(self.outputs)),
            p + "config": json.dumps(self.config.to_dict(), sort_keys=True),
            p + "config_hash": self.src.config_hash,
            p + "version": __version__,
            p + "opset": str(OPSET),
            p + "exporter": EXPORTER,
            p + "source": self.src.source,
        }
        if self.src.step is not None:
            meta[p + "step"] = str(self.src.step)
        meta.update({p + k: v for k, v in self.extra_meta().items()})
        meta.update({p + k: v for k, v in (extra or {}).items()})
        return meta

    def random_feeds(self) -> list[dict[str, np.ndarray]]:
        g = torch.Generator().manual_seed(self.seed + 17)
        H, W = self.size
        return [{n: torch.rand((b, 3, H, W), generator=g).numpy() for n in self.inputs} for b in PARITY_BATCHES]

    def torch_run(self, feed: dict[str, np.ndarray]) -> np.ndarray:
        with torch.no_grad():
            return self.model(*(torch.from_numpy(feed[n]) for n in self.inputs)).numpy()

    def parity(self, path: Path, max_frames: int | None = None) -> dict:
        """max |onnxruntime - torch| on random inputs (batch 1 and 3) and on the gate frames (real triplet
        frames when calibration data is given, else synthetic ones; the first ``max_frames`` of them)."""
        frames = self.data.gate if max_frames is None else Frames(*(a[:max_frames] for a in self.data.gate))
        random, real = self.random_feeds(), self.real_feeds(frames)
        # torch first, then the session: only one of them holds a batch's activations at a time
        want = {id(f): self.torch_run(f) for f in random + real}
        m = rt.load_model(path, self.kind)

        def worst(feeds: list[dict[str, np.ndarray]]) -> float:
            # the largest batch first: the session's arena then serves the smaller ones from its chunks
            feeds = sorted(feeds, key=lambda f: -len(next(iter(f.values()))))
            return float(np.max([np.abs(m.run(**f) - want[id(f)]).max() for f in feeds]))  # NaN propagates

        out = {"random": worst(random), "frames": worst(real),
               "frames_source": self.data.info["source"], "frame_count": frames.count, "batches": list(PARITY_BATCHES),
               "atol": self.atol}
        out["max_abs"] = float(np.max([out["random"], out["frames"]]))
        return out

    def export_fp32(self, path: Path) -> dict:
        t0 = time.perf_counter()
        weights = sum(t.numel() * t.element_size() for t in self.model.state_dict().values())
        external = weights >= MAX_PROTO_BYTES  # one protobuf holds < 2 GiB: the weights go beside the graph
        H, W = self.size
        g = torch.Generator().manual_seed(self.seed)
        example = tuple(torch.rand((TRACE_BATCH, 3, H, W), generator=g) for _ in self.inputs)
        with tempfile.TemporaryDirectory(dir=path.parent) as scratch:
            proto = _torch_export(self.model, example, self.inputs, self.outputs, Path(scratch) if external else None)
        pin_output_dims(proto)
        check_dims(proto, self.inputs, self.outputs, (3, H, W), self.output_tail(), f"{self.kind} fp32")
        set_metadata(proto, self.metadata("fp32", {"external_data": external_data_path(path).name} if external else None))
        if not external:
            onnx.checker.check_model(proto, full_check=True)
        _save(proto, path, external)
        if external:
            onnx.checker.check_model(str(path), full_check=True)
        parity = self.parity(path)
        if not parity["max_abs"] <= self.atol:  # NaN fails too
            where = "random" if parity["random"] >= parity["frames"] else f"{parity['frames_source']} frame"
            raise ExportParityError(
                f"{self.kind} fp32: onnxruntime differs from torch by max |diff| {parity['max_abs']:.3g} on {where} inputs, "
                f"beyond the tolerance {self.atol:g}; nothing written")
        return self._entry(path, "fp32", parity, None, t0, "written", FP32_NOTE)

    def _entry(self, path: Path, precision: str, parity: dict | None, gate: dict | None, t0: float, status: str,
               note: str | None) -> dict:
        entry = {"model": self.kind, "precision": precision, "status": status, "input_size": list(self.size),
                 "parity_max_abs": None if parity is None else parity["max_abs"], "parity": parity, "gate": gate,
                 "note": note}
        if status == "written":
            entry.update(bytes=path.stat().st_size, sha256=sha256_file(path))
            data = external_data_path(path)
            if data.is_file():
                entry["external_data"] = {"file": data.name, "bytes": data.stat().st_size, "sha256": sha256_file(data)}
        entry["seconds"] = round(time.perf_counter() - t0, 3)
        return entry

    def finish_variant(self, proto: onnx.ModelProto, path: Path, precision: str, extra: dict[str, str]) -> None:
        check_dims(proto, self.inputs, self.outputs, (3, *self.size), self.output_tail(), f"{self.kind} {precision}")
        set_metadata(proto, self.metadata(precision, extra))
        onnx.checker.check_model(proto)
        _save(proto, path)

    def export_fp16(self, fp32: Path, path: Path) -> dict:
        from onnxruntime.transformers.float16 import DEFAULT_OP_BLOCK_LIST, convert_float_to_float16

        t0 = time.perf_counter()
        block = list(DEFAULT_OP_BLOCK_LIST) + [op for op in FP16_KEEP_FP32 if op not in DEFAULT_OP_BLOCK_LIST]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            proto = convert_float_to_float16(onnx.load(str(fp32)), keep_io_types=True, op_block_list=block)
        sort_nodes(proto)
        self.finish_variant(proto, path, "fp16", {"fp32_ops": json.dumps(list(FP16_KEEP_FP32))})
        parity = self.parity(path, VARIANT_PARITY_FRAMES)
        parity["atol"] = None  # recorded, not gated
        status = "written" if np.isfinite(parity["max_abs"]) else "REJECTED"
        gate = {"finite": status == "written", "passed": status == "written"}
        return self._entry(path, "fp16", parity, gate, t0, status, FP16_NOTE)


class _RefinerJob(_Job):
    kind = "refiner"
    atol = REFINER_ATOL

    def __init__(self, src: _Source, size: tuple[int, int], data: Data, seed: int) -> None:
        super().__init__(src, size, data, seed)
        self.inputs = tuple(rt.REFINER_INPUTS[: self.config.views])
        self.outputs = (rt.REFINER_OUTPUT,)

    def output_tail(self) -> tuple[int, ...]:
        return (self.config.views, 3, *self.size)

    def extra_meta(self) -> dict[str, str]:
        return {"conditions": self.config.conditions,
                "normalization": "inputs RGB float32 NCHW [B, 3, H, W] in [0, 1] (coarse render, real reference "
                                 "frame, body normal map: as many as the conditions use), not normalised; output "
                                 "[B, V, 3, H, W] in (0, 1), views in the order coarse, reference, normal"}

    def feeds(self, frames: Frames) -> list[dict[str, np.ndarray]]:
        batch = refiner_frames_per_batch(self.size)
        arrays = {"coarse": frames.coarse, "reference": frames.reference, "normal": frames.normal}
        return [{n: _nchw(arrays[n][i:i + batch]) for n in self.inputs} for i in range(0, frames.count, batch)]

    def real_feeds(self, frames: Frames) -> list[dict[str, np.ndarray]]:
        return self.feeds(frames)

    def mean_psnr(self, path: Path) -> float:
        m = rt.load_model(path, "refiner")
        refined = np.concatenate([m.run(**f)[:, 0] for f in self.feeds(self.data.gate)])
        return float(psnr(np.clip(refined, 0, 1), _nchw(self.data.gate.gt)).mean())

    def gate(self, fp32: Path, variant: Path) -> dict:
        a, b = self.mean_psnr(fp32), self.mean_psnr(variant)
        coarse = float(psnr(self.data.gate.coarse, self.data.gate.gt).mean())
        return {"metric": "mean PSNR (dB) of the refined coarse view vs GT", "frames": self.data.gate.count,
                "data": self.data.info["source"], "coarse_psnr": coarse, "fp32_psnr": a, "int8_psnr": b,
                "psnr_drop": a - b, "max_drop": INT8_MAX_PSNR_DROP_DB, "passed": bool(a - b <= INT8_MAX_PSNR_DROP_DB)}

    def export_int8(self, fp32: Path, path: Path) -> dict:
        from onnxruntime.quantization import CalibrationDataReader, QuantFormat, QuantType, quantize_static
        from onnxruntime.quantization.shape_inference import quant_pre_process

        class Reader(CalibrationDataReader):
            def __init__(self, feeds: list[dict[str, np.ndarray]]) -> None:
                self._it = iter(feeds)

            def get_next(self) -> dict[str, np.ndarray] | None:
                return next(self._it, None)

        t0 = time.perf_counter()
        pre = path.with_name(path.stem + ".pre.onnx")
        try:
            with warnings.catch_warnings(), _quiet_logging(), _calibration_without_memory_pattern():
                warnings.simplefilter("ignore")
                # ONNX shape inference only: onnxruntime's symbolic shape inference gives up on these graphs
                # ("Incomplete symbolic shape inference") after seconds of work.
                quant_pre_process(str(fp32), str(pre), skip_symbolic_shape=True)
                quantize_static(str(pre), str(path), Reader(self.feeds(self.data.calibration)),
                                quant_format=QuantFormat.QDQ, per_channel=True, activation_type=QuantType.QUInt8,
                                weight_type=QuantType.QInt8, op_types_to_quantize=list(REFINER_INT8_OPS))
        finally:
            pre.unlink(missing_ok=True)
        how = (f"static QDQ of {'/'.join(REFINER_INT8_OPS)}: per-channel QInt8 weights, QUInt8 activations, MinMax "
               f"calibration on {self.data.calibration.count} {self.data.info['source']} frames; normalisations, "
               f"softmax and the logit/sigmoid output stay fp32")
        self.finish_variant(onnx.load(str(path)), path, "int8", {"quantization": how})
        gate = self.gate(fp32, path)
        parity = self.parity(path, VARIANT_PARITY_FRAMES)
        parity["atol"] = None
        status = "written" if gate["passed"] else "REJECTED"
        return self._entry(path, "int8", parity, gate, t0, status, how)


class _ExaminerJob(_Job):
    kind = "examiner"
    atol = EXAMINER_ATOL

    def __init__(self, src: _Source, size: tuple[int, int], data: Data, seed: int) -> None:
        super().__init__(src, size, data, seed)
        self.inputs = rt.EXAMINER_INPUTS
        self.outputs = (rt.EXAMINER_OUTPUT,)

    def output_tail(self) -> tuple[int, ...]:
        return ()

    def extra_meta(self) -> dict[str, str]:
        return {"normalization": "inputs RGB float32 NCHW [B, 3, S, S] in [0, 1]; the graph normalises internally "
                                 "with mean = std = 0.5; output: similarity score [B] in [0, 1]"}

    def pairs(self, frames: Frames) -> tuple[np.ndarray, np.ndarray]:
        """(candidate, reference) NCHW: first every coarse render, then every real frame, against the reference."""
        cand = np.concatenate([frames.coarse, frames.gt])
        ref = np.concatenate([frames.reference, frames.reference])
        return _nchw(cand), _nchw(ref)

    def real_feeds(self, frames: Frames, batch: int = 16) -> list[dict[str, np.ndarray]]:
        c, r = self.pairs(frames)
        return [{"candidate": c[i:i + batch], "reference": r[i:i + batch]} for i in range(0, len(c), batch)]

    def scores(self, path: Path) -> np.ndarray:
        """[n, 2] scores of (coarse, real) against each gate frame's reference, one ``choose`` per frame as
        the runtime's augment makes it (a batch of the K = 2 candidates: dynamic int8 quantizes each batch
        with its own activation range, so a score depends on the batch it is computed in)."""
        m = rt.load_model(path, "examiner")
        g = self.data.gate
        return np.stack([m.choose(np.stack([c, t]), r).scores for c, t, r in zip(g.coarse, g.gt, g.reference)])

    def gate(self, fp32: Path, variant: Path) -> dict:
        return decision_agreement(self.scores(fp32), self.scores(variant)) | {"data": self.data.info["source"]}

    def export_int8(self, fp32: Path, path: Path) -> dict:
        from onnxruntime.quantization import QuantType, quantize_dynamic

        t0 = time.perf_counter()
        proto = onnx.load(str(fp32))
        weights = {i.name for i in proto.graph.initializer}
        # Only the MatMul/Gemm with a weight (the Linear layers): the attention's activation x activation
        # MatMuls stay fp32, and Conv is never quantized (dynamic Conv -> ConvInteger, no CPU kernel).
        exclude = [n.name for n in proto.graph.node if n.op_type in ("MatMul", "Gemm") and not (set(n.input[:2]) & weights)]
        with warnings.catch_warnings(), _quiet_logging():
            warnings.simplefilter("ignore")
            quantize_dynamic(str(fp32), str(path), op_types_to_quantize=["MatMul", "Gemm"], per_channel=False,
                             weight_type=QuantType.QInt8, nodes_to_exclude=exclude)
        how = "dynamic int8: QInt8 weights of the MatMul/Gemm with a weight (Linear layers); Conv and attention MatMuls in fp32"
        quantized = onnx.load(str(path))
        if any(n.op_type == "ConvInteger" for n in quantized.graph.node):
            raise ExportError(f"{path}: dynamic quantization produced ConvInteger (no CPU kernel)")
        self.finish_variant(quantized, path, "int8", {"quantization": how})
        gate = self.gate(fp32, path)
        parity = self.parity(path, VARIANT_PARITY_FRAMES)
        parity["atol"] = None
        status = "written" if gate["passed"] else "REJECTED"
        return self._entry(path, "int8", parity, gate, t0, status, how)


def decision_agreement(fp32: np.ndarray, other: np.ndarray, threshold: float = KEEP_THRESHOLD) -> dict:
    """Examiner decisions from two [n, K] score arrays (per frame, K candidates scored against the real
    frame): the chosen candidate per frame (ties -> the lower index) and keep = score >= threshold per
    pair; agreement fractions, the closest fp32 margins and the gate."""
    fp32, other = np.asarray(fp32, np.float64), np.asarray(other, np.float64)
    choice = float(np.mean(np.argmax(fp32, axis=1) == np.argmax(other, axis=1)))
    keep = float(np.mean((fp32 >= threshold) == (other >= threshold)))
    agreement = min(choice, keep)
    top2 = np.sort(fp32, axis=1)[:, -2:] if fp32.shape[1] > 1 else None
    return {"metric": f"agreement of Examiner decisions with fp32 (choice among {fp32.shape[1]} candidates; score >= {threshold})",
            "frames": int(fp32.shape[0]), "choice_agreement": choice, "keep_agreement": keep, "agreement": agreement,
            "max_abs_score_diff": float(np.abs(fp32 - other).max()),
            "fp32_min_choice_margin": None if top2 is None else float((top2[:, 1] - top2[:, 0]).min()),
            "fp32_min_threshold_margin": float(np.abs(fp32 - threshold).min()),
            "min_agreement": INT8_MIN_AGREEMENT, "passed": bool(agreement >= INT8_MIN_AGREEMENT)}


@contextlib.contextmanager
def _calibration_without_memory_pattern():
    """onnxruntime's calibration session built with the memory pattern off (as ``runtime.models`` builds
    its sessions: the pattern's block comes on top of the arena chunks of the first run, twice the
    activations' memory), for the duration. Otherwise the session onnxruntime builds: no graph
    optimisation, the calibrator's providers; the same runs, so the same ranges."""
    import onnxruntime as ort
    from onnxruntime.quantization.calibrate import CalibraterBase

    def create_inference_session(self) -> None:
        opts = ort.SessionOptions()
        opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_DISABLE_ALL
        opts.enable_mem_pattern = False
        self.infer_session = ort.InferenceSession(self.augmented_model_path, sess_options=opts,
                                                  providers=self.execution_providers)

    original = CalibraterBase.create_inference_session
    CalibraterBase.create_inference_session = create_inference_session
    try:
        yield
    finally:
        CalibraterBase.create_inference_session = original


@contextlib.contextmanager
def _quiet_logging():
    """Silence the quantization tools' INFO/WARNING logging for the duration."""
    import logging

    root = logging.getLogger()
    level = root.level
    root.setLevel(logging.ERROR)
    try:
        yield
    finally:
        root.setLevel(level)


# --------------------------------------------------------------------------------------------------
# sizes and jobs


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
                          f"pass a size that is (--size)")
    return hw


def refiner_frames_per_batch(size: tuple[int, int]) -> int:
    """Frames per Refiner batch at this (H, W): REFINER_BATCH_PIXELS and REFINER_MAX_BATCH."""
    return max(1, min(REFINER_MAX_BATCH, REFINER_BATCH_PIXELS // (size[0] * size[1])))


def _job(kind: str, model_or_ckpt: Any, size: Any, calibration: Sequence[str | os.PathLike] | None, seed: int,
         calibration_frames: int, gate_frames: int, triplets: Any = None) -> _Job:
    src = _load(kind, model_or_ckpt)
    if kind == "refiner":
        hw = refiner_export_size(src.model.config, size, calibration, src.model.total_downsample)
    else:
        s = src.model.config.img_size
        hw = (s, s)
        if size is not None and _square(size) != hw:
            raise ExportError(f"size: the Examiner's input size is fixed by its config.img_size {s}, got {size!r}")
    data = load_data(calibration, hw, calibration_frames=calibration_frames, gate_frames=gate_frames, seed=seed,
                     triplets=triplets)
    return (_RefinerJob if kind == "refiner" else _ExaminerJob)(src, hw, data, seed)


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


def _export_into(job: _Job, folder: Path, variants: tuple[str, ...]) -> dict[str, dict]:
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


def _model_report(job: _Job) -> dict:
    return {"source": job.src.source, "step": job.src.step, "config_hash": job.src.config_hash,
            "config": job.config.to_dict(), "input_size": list(job.size), "inputs": list(job.inputs),
            "outputs": list(job.outputs), "data": job.data.info,
            **({"conditions": job.config.conditions} if job.kind == "refiner" else {})}


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
                variants: Sequence[str] | str = VARIANTS, calibration: Sequence[str | os.PathLike] | None = None,
                size: int | Sequence[int] | None = None, overwrite: bool = False, seed: int = 0,
                calibration_frames: int = 32, gate_frames: int = 32,
                progress: Callable[[str], None] | None = None) -> dict:
    """``trioman export onnx``: the Refiner and/or the Examiner (modules, checkpoint files or run folders)
    -> an output folder of ONNX files + export.json; -> the report (what export.json holds).

    ``size`` is the Refiner's export size (int or (H, W)); the Examiner's is its config's. The folder
    is written as a temporary sibling renamed into place: an error (ExportParityError, ...) leaves
    nothing, and a non-empty ``out`` is replaced only with ``overwrite``.
    """
    if refiner is None and examiner is None:
        raise ExportError("nothing to export: give a Refiner and/or an Examiner checkpoint (--refiner / --examiner)")
    if out is None:
        raise ExportError("out: the output folder is required (--out)")
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
        from trioman.toolkit.triplets import TripletSet

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
