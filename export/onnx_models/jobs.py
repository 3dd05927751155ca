"""One model's export: fp32 with its parity check, int8 with its gate, fp16; each an export.json entry."""

from __future__ import annotations

import abc
import contextlib
import json
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np
import onnx
import torch

from trioman import __version__
from trioman.export.onnx_models.checkpoints import Source
from trioman.export.onnx_models.constants import (
    BATCH_AXIS,
    EXAMINER_ATOL,
    EXPORTER,
    FP16_KEEP_FP32,
    FP16_NOTE,
    FP32_NOTE,
    HEIGHT_AXIS,
    INT8_MAX_PSNR_DROP_DB,
    INT8_MIN_AGREEMENT,
    KEEP_THRESHOLD,
    MAX_PROTO_BYTES,
    OPSET,
    PARITY_BATCHES,
    REFINER_ATOL,
    REFINER_INT8_OPS,
    TRACE_BATCH,
    VARIANT_PARITY_FRAMES,
    WIDTH_AXIS,
)
from trioman.export.onnx_models.errors import ExportError, ExportParityError
from trioman.export.onnx_models.frames import Data, Frames, nchw, refiner_frames_per_batch
from trioman.export.onnx_models.graph import (
    check_dims,
    external_data_path,
    pin_output_dims,
    save_proto,
    set_metadata,
    sort_nodes,
    torch_export,
)
from trioman.runtime import onnx_models as rt
from trioman.runtime.formats.avatar import sha256_file
from trioman.runtime.metrics import psnr


class Job(abc.ABC):
    """What the exports of one model share: the torch model, its size, names, metadata and data."""

    kind = ""
    atol = 0.0

    def __init__(self, src: Source, size: tuple[int, int], data: Data, seed: int) -> None:
        self.src, self.model, self.size, self.data, self.seed = src, src.model, size, data, seed
        self.config = self.model.config
        self.inputs: tuple[str, ...] = ()
        self.outputs: tuple[str, ...] = ()

    # subclasses: names, dims, metadata extras, real-frame feeds, gate
    def input_tail(self) -> tuple[int | str, ...]:
        """Each input's dimensions after the batch (an int: static; a str: the symbolic dim's name)."""
        return (3, *self.size)

    @abc.abstractmethod
    def output_tail(self) -> tuple[int | str, ...]:
        """The output's dimensions after the batch (as ``input_tail``)."""

    def dynamic_axes(self) -> dict[str, dict[int, str]]:
        """The symbolic dims of every input and output, {axis: name}: those the tails name, and the batch."""
        tails = {**{n: self.input_tail() for n in self.inputs}, **{n: self.output_tail() for n in self.outputs}}
        return {n: {0: BATCH_AXIS, **{1 + j: d for j, d in enumerate(tail) if isinstance(d, str)}} for n, tail in tails.items()}

    def other_sizes(self) -> list[tuple[int, int]]:
        """Image sizes besides ``size`` the parity is measured at (a graph of symbolic H and W)."""
        return []

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

    def random_feeds(self, size: tuple[int, int] | None = None,
                     batches: tuple[int, ...] = PARITY_BATCHES) -> list[dict[str, np.ndarray]]:
        """Random images in [0, 1] at ``size`` (default: the export size), one feed per batch size."""
        g = torch.Generator().manual_seed(self.seed + 17)
        H, W = size or self.size
        return [{n: torch.rand((b, 3, H, W), generator=g).numpy() for n in self.inputs} for b in batches]

    def torch_run(self, feed: dict[str, np.ndarray]) -> np.ndarray:
        with torch.no_grad():
            return self.model(*(torch.from_numpy(feed[n]) for n in self.inputs)).numpy()

    def parity(self, path: Path, max_frames: int | None = None) -> dict:
        """max |onnxruntime - torch| on random inputs (batch 1 and 3), on the gate frames (real triplet
        frames when calibration data is given, else synthetic ones; the first ``max_frames`` of them), and on
        random inputs of batch 1 at each of ``other_sizes``."""
        frames = self.data.gate if max_frames is None else Frames(*(None if a is None else a[:max_frames] for a in self.data.gate))
        random, real = self.random_feeds(), self.real_feeds(frames)
        others = {f"{h}x{w}": self.random_feeds((h, w), (1,)) for h, w in self.other_sizes()}
        # torch first, then the session: only one of them holds a batch's activations at a time
        want = {id(f): self.torch_run(f) for f in random + real + [f for feeds in others.values() for f in feeds]}
        m = rt.load_model(path, self.kind)

        def worst(feeds: list[dict[str, np.ndarray]]) -> float:
            # the largest batch first: the session's arena then serves the smaller ones from its chunks
            feeds = sorted(feeds, key=lambda f: -len(next(iter(f.values()))))
            return float(np.max([np.abs(m.run(**f) - want[id(f)]).max() for f in feeds]))  # NaN propagates

        out = {"random": worst(random), "frames": worst(real),
               "frames_source": self.data.info["source"], "frame_count": frames.count, "batches": list(PARITY_BATCHES),
               "atol": self.atol}
        if others:  # H x W -> max |diff| there
            out["other_sizes"] = {size: worst(feeds) for size, feeds in others.items()}
        out["max_abs"] = float(np.max([out["random"], out["frames"], *out.get("other_sizes", {}).values()]))
        return out

    @staticmethod
    def worst_inputs(parity: dict) -> str:
        """Which inputs gave ``parity``'s largest difference, in words."""
        cases = {"random": parity["random"], f"{parity['frames_source']} frame": parity["frames"],
                 **{f"random {size}": v for size, v in parity.get("other_sizes", {}).items()}}
        return max(cases, key=lambda k: np.inf if np.isnan(cases[k]) else cases[k])  # NaN is the worst

    def export_fp32(self, path: Path) -> dict:
        t0 = time.perf_counter()
        weights = sum(t.numel() * t.element_size() for t in self.model.state_dict().values())
        external = weights >= MAX_PROTO_BYTES  # one protobuf holds < 2 GiB: the weights go beside the graph
        H, W = self.size
        g = torch.Generator().manual_seed(self.seed)
        example = tuple(torch.rand((TRACE_BATCH, 3, H, W), generator=g) for _ in self.inputs)
        axes = self.dynamic_axes()
        with tempfile.TemporaryDirectory(dir=path.parent) as scratch:
            proto = torch_export(self.model, example, self.inputs, self.outputs, Path(scratch) if external else None, axes)
        pin_output_dims(proto, {n: axes[n] for n in self.outputs})
        check_dims(proto, self.inputs, self.outputs, self.input_tail(), self.output_tail(), f"{self.kind} fp32")
        set_metadata(proto, self.metadata("fp32", {"external_data": external_data_path(path).name} if external else None))
        if not external:
            onnx.checker.check_model(proto, full_check=True)
        save_proto(proto, path, external)
        if external:
            onnx.checker.check_model(str(path), full_check=True)
        parity = self.parity(path)
        if not parity["max_abs"] <= self.atol:  # NaN fails too
            where = self.worst_inputs(parity)
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
        check_dims(proto, self.inputs, self.outputs, self.input_tail(), self.output_tail(), f"{self.kind} {precision}")
        set_metadata(proto, self.metadata(precision, extra))
        onnx.checker.check_model(proto)
        save_proto(proto, path)

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


class RefinerJob(Job):
    kind = "refiner"
    atol = REFINER_ATOL

    def __init__(self, src: Source, size: tuple[int, int], data: Data, seed: int) -> None:
        super().__init__(src, size, data, seed)
        self.inputs = tuple(rt.REFINER_INPUTS[: self.config.views])
        self.outputs = (rt.REFINER_OUTPUT,)

    @property
    def multiple(self) -> int:
        """The total downsampling: the graph takes H and W that are multiples of it."""
        return int(self.model.total_downsample)

    def input_tail(self) -> tuple[int | str, ...]:
        return (3, HEIGHT_AXIS, WIDTH_AXIS)

    def output_tail(self) -> tuple[int | str, ...]:
        return (self.config.views, 3, HEIGHT_AXIS, WIDTH_AXIS)

    def other_sizes(self) -> list[tuple[int, int]]:
        """One size besides the export size, each side changed by one multiple (the height down where it can be,
        the width up), so a size baked into the graph, or H and W swapped, shows in the parity."""
        (H, W), m = self.size, self.multiple
        return [(H - m if H > m else H + m, W + m)]

    def extra_meta(self) -> dict[str, str]:
        return {"conditions": self.config.conditions, rt.SIZE_MULTIPLE_KEY: str(self.multiple),
                "normalization": "inputs RGB float32 NCHW [B, 3, H, W] in [0, 1] (coarse render, reference: a real "
                                 "frame, or with conditions warp* the aligned reference filled with the coarse render, "
                                 "body normal map: as many as the conditions use), not normalised; output "
                                 "[B, V, 3, H, W] in (0, 1), views in the order of view_images (coarse, reference, "
                                 "normal; warp*: aligned, coarse, normal)"}

    def feeds(self, frames: Frames) -> list[dict[str, np.ndarray]]:
        batch = refiner_frames_per_batch(self.size)
        reference = frames.reference
        if self.config.conditions in rt.ALIGNED_CONDITIONS:
            if frames.aligned is None:
                raise ExportError(f"calibration: a {self.config.conditions!r} Refiner takes aligned references; these triplets "
                                  "hold none (version 1: build them again)")
            reference = frames.aligned
        arrays = {"coarse": frames.coarse, "reference": reference, "normal": frames.normal}
        return [{n: nchw(arrays[n][i:i + batch]) for n in self.inputs} for i in range(0, frames.count, batch)]

    def real_feeds(self, frames: Frames) -> list[dict[str, np.ndarray]]:
        return self.feeds(frames)

    def mean_psnr(self, path: Path) -> float:
        m = rt.load_model(path, "refiner")
        refined = np.concatenate([m.run(**f)[:, 0] for f in self.feeds(self.data.gate)])
        return float(psnr(np.clip(refined, 0, 1), nchw(self.data.gate.gt)).mean())

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
                                weight_type=QuantType.QInt8, op_types_to_quantize=list(REFINER_INT8_OPS),
                                # 7-bit weights: x86 CPUs without VNNI multiply u8 x s8 pairs into 16-bit sums that
                                # saturate with full-range weights (onnxruntime's quantization guide), so the model
                                # would give other numbers there than on the machine that exported it
                                reduce_range=True)
        finally:
            pre.unlink(missing_ok=True)
        how = (f"static QDQ of {'/'.join(REFINER_INT8_OPS)}: per-channel QInt8 weights (7-bit range), QUInt8 activations, MinMax "
               f"calibration on {self.data.calibration.count} {self.data.info['source']} frames; normalisations, "
               f"softmax and the logit/sigmoid output stay fp32")
        self.finish_variant(onnx.load(str(path)), path, "int8", {"quantization": how})
        gate = self.gate(fp32, path)
        parity = self.parity(path, VARIANT_PARITY_FRAMES)
        parity["atol"] = None
        status = "written" if gate["passed"] else "REJECTED"
        return self._entry(path, "int8", parity, gate, t0, status, how)


class ExaminerJob(Job):
    kind = "examiner"
    atol = EXAMINER_ATOL

    def __init__(self, src: Source, size: tuple[int, int], data: Data, seed: int) -> None:
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
        return nchw(cand), nchw(ref)

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
    """onnxruntime's calibration session built with the memory pattern off (as ``runtime.onnx_models`` builds
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
