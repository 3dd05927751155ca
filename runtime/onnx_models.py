"""The Refiner and the Examiner as ONNX models under onnxruntime (numpy + onnxruntime + OpenCV; no torch, no
onnx): ``RefinerModel``, ``ExaminerModel``, ``load_model``; ``pad_to_multiple`` / ``crop_to``, how a Refiner of any
size takes images whose sides are not multiples of its total downsampling (the torch wrappers use them too).

The files, their required ``trioman.*`` metadata and how the classes use them: docs/formats.md, "ONNX
models" ("Metadata" and "Using them").
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any, NamedTuple, Sequence

import numpy as np

from trioman.runtime.formats.common import FormatError, require_file

META_PREFIX = "trioman."
FORMAT = "trioman-onnx"
FORMAT_VERSION = "1"
KINDS = ("refiner", "examiner")
PRECISIONS = ("fp32", "int8", "fp16")
# Keys every model needs (without the prefix); the Refiner also needs "conditions".
REQUIRED_KEYS = ("format", "format_version", "kind", "precision", "input_size", "inputs", "outputs")
# A Refiner exported with symbolic H and W carries its total downsampling under this key: it takes any image size
# (sides padded to multiples of it); without the key a model takes "input_size" only.
SIZE_MULTIPLE_KEY = "size_multiple"

REFINER_INPUTS = ("coarse", "reference", "normal")  # graph inputs in view order (toolkit.refiner.INPUT_NAMES)
REFINER_OUTPUT = "refined"
REFINER_VIEWS = {"none": 1, "tex": 2, "tex+geo": 3, "warp": 2, "warp+geo": 3}  # conditions -> V
ALIGNED_CONDITIONS = ("warp", "warp+geo")  # the reference input is the geometry-aligned reference (runtime/aligned.py)
EXAMINER_INPUTS = ("candidate", "reference")
EXAMINER_OUTPUT = "score"

OPTIMIZATION_LEVELS = ("disable", "basic", "extended", "all")


def _key(name: str) -> str:
    return META_PREFIX + name


# --------------------------------------------------------------------------------------------------
# opening a file


def _session(path: Path, optimization: str, threads: int | None) -> Any:
    """A CPU onnxruntime session of ``path``; a missing or unparsable file -> FormatError."""
    import onnxruntime as ort

    if optimization not in OPTIMIZATION_LEVELS:
        raise ValueError(f"optimization: expected one of {OPTIMIZATION_LEVELS}, got {optimization!r}")
    if threads is not None and (not isinstance(threads, int) or isinstance(threads, bool) or threads < 1):
        raise ValueError(f"threads: expected a positive integer or None (onnxruntime's default), got {threads!r}")
    require_file(path)
    levels = {
        "disable": ort.GraphOptimizationLevel.ORT_DISABLE_ALL,
        "basic": ort.GraphOptimizationLevel.ORT_ENABLE_BASIC,
        "extended": ort.GraphOptimizationLevel.ORT_ENABLE_EXTENDED,
        "all": ort.GraphOptimizationLevel.ORT_ENABLE_ALL,
    }
    opts = ort.SessionOptions()
    opts.log_severity_level = 3
    opts.graph_optimization_level = levels[optimization]
    # No memory pattern: the block it plans for the second run comes on top of the arena chunks the first
    # run took (twice the activations' memory); without it the arena reuses those chunks.
    opts.enable_mem_pattern = False
    if threads is not None:
        opts.intra_op_num_threads = threads
    try:
        return ort.InferenceSession(str(path), sess_options=opts, providers=["CPUExecutionProvider"])
    except Exception as err:  # onnxruntime raises several types for "cannot parse / cannot build"
        first = (str(err).splitlines() or [""])[0][:300]
        raise FormatError(f"{path}: not a loadable ONNX model ({type(err).__name__}: {first})") from None


def _metadata(session: Any) -> dict[str, str]:
    return dict(session.get_modelmeta().custom_metadata_map)


def read_metadata(path: str | os.PathLike) -> dict[str, str]:
    """All metadata_props of the ONNX file at ``path`` (the ``trioman.*`` keys and any others), unchecked.

    A missing or unparsable file -> FormatError.
    """
    return _metadata(_session(Path(path), "disable", 1))


class _Header(NamedTuple):
    kind: str
    precision: str
    size: tuple[int, int]
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    multiple: int | None  # trioman.size_multiple: the graph takes H, W multiples of it; None: exactly ``size``


def _json_names(meta: dict[str, str], field: str, path: Path) -> tuple[str, ...]:
    raw = meta[_key(field)]
    try:
        names = json.loads(raw)
    except ValueError:
        names = None
    if not isinstance(names, list) or not names or not all(isinstance(n, str) and n for n in names):
        raise FormatError(f"{path}: metadata {_key(field)!r}: expected a JSON list of names, got {raw!r}")
    return tuple(names)


def _check_header(meta: dict[str, str], path: Path) -> _Header:
    """The required metadata keys, checked; FormatError naming the file and the key otherwise."""
    for name in REQUIRED_KEYS:
        if _key(name) not in meta:
            raise FormatError(f"{path}: metadata {_key(name)!r} missing: not a model written by `trioman export onnx`")
    if meta[_key("format")] != FORMAT:
        raise FormatError(f"{path}: metadata {_key('format')!r}: expected {FORMAT!r}, got {meta[_key('format')]!r}")
    version = meta[_key("format_version")]
    if version != FORMAT_VERSION:
        raise FormatError(f"{path}: metadata {_key('format_version')!r}: unknown version {version!r} "
                          f"(this trioman reads version {FORMAT_VERSION!r}; re-export the model)")
    kind = meta[_key("kind")]
    if kind not in KINDS:
        raise FormatError(f"{path}: metadata {_key('kind')!r}: expected one of {KINDS}, got {kind!r}")
    precision = meta[_key("precision")]
    if precision not in PRECISIONS:
        raise FormatError(f"{path}: metadata {_key('precision')!r}: expected one of {PRECISIONS}, got {precision!r}")
    raw = meta[_key("input_size")]
    try:
        size = tuple(int(v) for v in raw.split(","))
    except ValueError:
        size = ()
    if len(size) != 2 or min(size) < 1:
        raise FormatError(f"{path}: metadata {_key('input_size')!r}: expected 'H,W' (positive integers), got {raw!r}")
    multiple = None
    if _key(SIZE_MULTIPLE_KEY) in meta:
        raw = meta[_key(SIZE_MULTIPLE_KEY)]
        multiple = int(raw) if raw.isdigit() else 0
        if multiple < 1:
            raise FormatError(f"{path}: metadata {_key(SIZE_MULTIPLE_KEY)!r}: expected a positive integer, got {raw!r}")
        if size[0] % multiple or size[1] % multiple:
            raise FormatError(f"{path}: metadata {_key('input_size')!r} {size[0]},{size[1]} is not a multiple of "
                              f"{_key(SIZE_MULTIPLE_KEY)!r} {multiple} (stale or mismatched model)")
    return _Header(kind, precision, size, _json_names(meta, "inputs", path), _json_names(meta, "outputs", path), multiple)


def _check_graph(session: Any, header: _Header, path: Path, output_tail: tuple[int | None, ...]) -> None:
    """The graph's inputs/outputs against the metadata: names, float32, a symbolic batch, H and W static at
    ``input_size`` or, with ``size_multiple``, symbolic; the other dims static. ``None`` in ``output_tail``: H or W."""
    H, W = header.size
    inputs = session.get_inputs()
    names = tuple(i.name for i in inputs)
    if names != header.inputs:
        raise FormatError(f"{path}: graph inputs {list(names)} disagree with metadata {_key('inputs')!r} "
                          f"{list(header.inputs)} (stale or mismatched model)")
    for i in inputs:
        if i.type != "tensor(float)":
            raise FormatError(f"{path}: graph input {i.name!r}: expected float32, got {i.type}")
        shape = list(i.shape)
        if header.multiple is None:
            if len(shape) != 4 or isinstance(shape[0], int) or shape[1:] != [3, H, W]:
                raise FormatError(f"{path}: graph input {i.name!r}: shape {shape} disagrees with metadata "
                                  f"{_key('input_size')!r} {H},{W} (expected [batch, 3, {H}, {W}]; stale or mismatched model)")
        elif len(shape) != 4 or any(isinstance(d, int) for d in (shape[0], *shape[2:])) or shape[1] != 3:
            raise FormatError(f"{path}: graph input {i.name!r}: shape {shape} disagrees with metadata "
                              f"{_key(SIZE_MULTIPLE_KEY)!r} (expected [batch, 3, height, width], symbolic height and "
                              f"width; stale or mismatched model)")
    outputs = session.get_outputs()
    names = tuple(o.name for o in outputs)
    if names != header.outputs:
        raise FormatError(f"{path}: graph outputs {list(names)} disagree with metadata {_key('outputs')!r} {list(header.outputs)}")
    shape = list(outputs[0].shape)
    if outputs[0].type != "tensor(float)":
        raise FormatError(f"{path}: graph output {names[0]!r}: expected float32, got {outputs[0].type}")
    # Output dims may be left symbolic by the exporter; those that are static must agree.
    if len(shape) != 1 + len(output_tail) or isinstance(shape[0], int) or any(
        isinstance(got, int) and got != want for got, want in zip(shape[1:], output_tail)
    ):
        want = ", ".join("?" if d is None else str(d) for d in output_tail)
        raise FormatError(f"{path}: graph output {names[0]!r}: shape {shape} disagrees with the metadata "
                          f"(expected [batch{', ' if want else ''}{want}]; stale or mismatched model)")


class _Opened(NamedTuple):
    path: Path
    session: Any
    meta: dict[str, str]
    header: _Header


def _open(path: str | os.PathLike, optimization: str, threads: int | None) -> _Opened:
    path = Path(path)
    session = _session(path, optimization, threads)
    meta = _metadata(session)
    return _Opened(path, session, meta, _check_header(meta, path))


def _float_images(x: Any, name: str) -> np.ndarray:
    a = np.asarray(x)
    if not np.issubdtype(a.dtype, np.floating):
        raise ValueError(f"{name}: expected float images in [0, 1], got dtype {a.dtype}")
    return a.astype(np.float32, copy=False)


def _hwc_batch(x: Any, name: str) -> tuple[np.ndarray, bool]:
    """[H, W, 3] or [B, H, W, 3] float -> ([B, H, W, 3] float32, was single)."""
    a = _float_images(x, name)
    if a.ndim == 3:
        a, single = a[None], True
    elif a.ndim == 4:
        single = False
    else:
        raise ValueError(f"{name}: expected an image [H, W, 3] or a batch [B, H, W, 3], got shape {list(a.shape)}")
    if a.shape[-1] != 3 or a.shape[0] < 1 or a.shape[1] < 1 or a.shape[2] < 1:
        raise ValueError(f"{name}: expected an image [H, W, 3] or a batch [B, H, W, 3], got shape {list(a.shape)}")
    return a, single


def _nchw(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a.transpose(0, 3, 1, 2))


def _check_nchw(x: Any, name: str, size: tuple[int, int] | None) -> np.ndarray:
    """[B, 3, H, W] float32; (H, W) = ``size`` unless it is None."""
    a = _float_images(x, name)
    if a.ndim != 4 or a.shape[1] != 3 or a.shape[0] < 1 or a.shape[2] < 1 or a.shape[3] < 1:
        raise ValueError(f"{name}: expected shape [B, 3, H, W], got {list(a.shape)}")
    if size is not None and tuple(a.shape[2:]) != size:
        raise ValueError(f"{name}: image size (H, W) = {tuple(a.shape[2:])} differs from the model's {size}")
    return np.ascontiguousarray(a)


def _positive_int(value: Any, name: str) -> int:
    if not isinstance(value, (int, np.integer)) or isinstance(value, bool) or value < 1:
        raise ValueError(f"{name}: expected a positive integer, got {value!r}")
    return int(value)


def padded_size(height: int, width: int, multiple: int) -> tuple[int, int]:
    """(``height``, ``width``) rounded up to multiples of ``multiple``."""
    height, width = _positive_int(height, "height"), _positive_int(width, "width")
    multiple = _positive_int(multiple, "multiple")
    return -(-height // multiple) * multiple, -(-width // multiple) * multiple


def pad_to_multiple(images: np.ndarray, multiple: int, axes: tuple[int, int] = (-3, -2)) -> np.ndarray:
    """``images`` with its height and width (``axes``; by default those of HWC arrays [..., H, W, C], ``(-2, -1)``
    for NCHW) padded on the bottom and on the right to the next multiples of ``multiple`` with copies of the last
    row and column (edge replicate): how a Refiner of any size takes sides that are not multiples of its total
    downsampling (docs/formats.md, "ONNX models"). ``images`` itself when both sides are multiples already;
    ``crop_to`` undoes it."""
    a = np.asarray(images)
    if a.ndim < 2:
        raise ValueError(f"images: expected an array with height and width axes {tuple(axes)}, got shape {list(a.shape)}")
    h_axis, w_axis = (int(ax) % a.ndim for ax in axes)
    H, W = padded_size(a.shape[h_axis], a.shape[w_axis], multiple)
    if (H, W) == (a.shape[h_axis], a.shape[w_axis]):
        return a
    pad = [(0, 0)] * a.ndim
    pad[h_axis], pad[w_axis] = (0, H - a.shape[h_axis]), (0, W - a.shape[w_axis])
    return np.pad(a, pad, mode="edge")


def crop_to(images: np.ndarray, size: tuple[int, int], axes: tuple[int, int] = (-3, -2)) -> np.ndarray:
    """The top-left ``size`` = (H, W) of ``images`` on its height and width ``axes`` (as for ``pad_to_multiple``,
    whose padding it removes); ``images`` itself when it is that size already."""
    a = np.asarray(images)
    h_axis, w_axis = (int(ax) % a.ndim for ax in axes)
    H, W = (_positive_int(v, "size") for v in size)
    if H > a.shape[h_axis] or W > a.shape[w_axis]:
        raise ValueError(f"size: {(H, W)} exceeds the images' {(a.shape[h_axis], a.shape[w_axis])}")
    if (H, W) == (a.shape[h_axis], a.shape[w_axis]):
        return a
    index = [slice(None)] * a.ndim
    index[h_axis], index[w_axis] = slice(0, H), slice(0, W)
    return a[tuple(index)]


class _Model:
    KIND = ""

    def __init__(self, path: str | os.PathLike, *, optimization: str = "all", threads: int | None = None) -> None:
        self._setup(_open(path, optimization, threads))

    @classmethod
    def _from_opened(cls, opened: _Opened) -> "_Model":
        model = cls.__new__(cls)
        model._setup(opened)
        return model

    def _setup(self, opened: _Opened) -> None:
        path, session, meta, header = opened
        if header.kind != self.KIND:
            raise FormatError(f"{path}: metadata {_key('kind')!r}: expected {self.KIND!r}, got {header.kind!r} "
                              f"(load it with {_CLASSES[header.kind].__name__} or load_model)")
        self.path = path
        self.meta = meta
        self.session = session
        self.size = header.size
        self.multiple = header.multiple
        self.precision = header.precision
        self.input_names = header.inputs
        self.output_names = header.outputs

    def __repr__(self) -> str:
        multiple = "" if self.multiple is None else f", multiple={self.multiple}"
        return f"{type(self).__name__}({str(self.path)!r}, precision={self.precision!r}, size={self.size}{multiple})"


class RefinerModel(_Model):
    """The exported Refiner. ``refine`` takes HWC images in [0, 1] of any size when the file gives ``multiple``
    (metadata ``trioman.size_multiple``, the model's total downsampling; sides that are not multiples of it are
    padded, edge replicate on the bottom and the right, and the output cropped back), else of exactly ``size``
    (an older fixed-size export). ``size`` = (H, W) is the size the export's parity and gates were measured at.

    ``conditions`` ("none", "tex", "tex+geo", "warp", "warp+geo") says which of coarse / reference / normal the graph takes
    (``input_names``); inputs it does not take are ignored. The graph's raw output holds every view
    [B, V, 3, H, W]; ``refine`` returns the refined coarse view (view 0).
    """

    KIND = "refiner"

    def _setup(self, opened: _Opened) -> None:
        super()._setup(opened)
        path, meta = opened.path, opened.meta
        if _key("conditions") not in meta:
            raise FormatError(f"{path}: metadata {_key('conditions')!r} missing: not a model written by `trioman export onnx`")
        conditions = meta[_key("conditions")]
        if conditions not in REFINER_VIEWS:
            raise FormatError(f"{path}: metadata {_key('conditions')!r}: expected one of {tuple(REFINER_VIEWS)}, got {conditions!r}")
        views = REFINER_VIEWS[conditions]
        if self.input_names != REFINER_INPUTS[:views]:
            raise FormatError(f"{path}: metadata {_key('inputs')!r}: expected {list(REFINER_INPUTS[:views])} for conditions "
                              f"{conditions!r}, got {list(self.input_names)}")
        if self.output_names != (REFINER_OUTPUT,):
            raise FormatError(f"{path}: metadata {_key('outputs')!r}: expected [{REFINER_OUTPUT!r}], got {list(self.output_names)}")
        _check_graph(opened.session, opened.header, path,
                     (views, 3, *((None, None) if self.multiple is not None else self.size)))
        self.conditions = conditions
        self.views = views

    def takes(self, height: int, width: int) -> bool:
        """Does ``refine`` take images of ``height`` x ``width``? Any size with ``multiple``, else ``size`` only."""
        return self.multiple is not None or (height, width) == tuple(self.size)

    def _feed(self, arrays: dict[str, Any], check) -> dict[str, np.ndarray]:
        """The NCHW feed of the inputs the graph takes; one batch size and one image size among them."""
        feed = {}
        for name in self.input_names:
            if arrays[name] is None:
                raise ValueError(f"{name}: required by this Refiner (conditions={self.conditions!r})")
            feed[name] = check(arrays[name], name)
        batch = {name: a.shape[0] for name, a in feed.items()}
        if len(set(batch.values())) != 1:
            raise ValueError(f"{self.input_names[-1]}: batch sizes differ between inputs: {batch}")
        for name, a in feed.items():
            if a.shape[2:] != feed["coarse"].shape[2:]:
                raise ValueError(f"{name}: image size (H, W) = {tuple(a.shape[2:])} differs from coarse's "
                                 f"{tuple(feed['coarse'].shape[2:])}")
        return feed

    def _run(self, feed: dict[str, np.ndarray]) -> np.ndarray:
        """The graph on ``feed`` [B, 3, H, W]: padded to ``multiple`` on the way in, cropped back on the way out."""
        if self.multiple is None:
            return self.session.run([REFINER_OUTPUT], feed)[0]
        size = feed["coarse"].shape[2:]
        feed = {name: np.ascontiguousarray(pad_to_multiple(a, self.multiple, (-2, -1))) for name, a in feed.items()}
        return np.ascontiguousarray(crop_to(self.session.run([REFINER_OUTPUT], feed)[0], size, (-2, -1)))

    def run(self, coarse: Any, reference: Any = None, normal: Any = None) -> np.ndarray:
        """The graph itself: float32 NCHW inputs [B, 3, H, W] in [0, 1] -> [B, V, 3, H, W] (views: coarse,
        reference, normal, as many as the conditions use); (H, W) as ``refine`` takes them, padded and cropped
        as there."""
        feed = self._feed({"coarse": coarse, "reference": reference, "normal": normal},
                          lambda x, name: _check_nchw(x, name, None if self.multiple is not None else self.size))
        return self._run(feed)

    def refine(self, coarse: Any, reference: Any = None, normal: Any = None) -> np.ndarray:
        """HWC float images in [0, 1], each [H, W, 3] or [B, H, W, 3], all of one size (any with ``multiple``,
        else ``size``) -> the refined coarse view, the shape of ``coarse``, float32 clipped to [0, 1].

        ``reference`` is required with conditions "tex" and "tex+geo" (a real frame near the view) and "warp",
        "warp+geo" (the aligned reference, filled with the coarse render where nothing was carried),
        ``normal`` (the body normal map) with "tex+geo" and "warp+geo"; unused inputs are ignored.
        """
        singles = {}

        def check(x: Any, name: str) -> np.ndarray:
            a, singles[name] = _hwc_batch(x, name)
            if not self.takes(*a.shape[1:3]):
                raise ValueError(f"{name}: image size (H, W) = {tuple(a.shape[1:3])} differs from the model's {self.size} "
                                 f"(this Refiner was exported for {self.size[0]}x{self.size[1]} images)")
            return _nchw(a)

        feed = self._feed({"coarse": coarse, "reference": reference, "normal": normal}, check)
        out = self._run(feed)[:, 0]  # [B, 3, H, W], the coarse view
        bad = int((~np.isfinite(out)).sum())
        if bad:  # the model's fault, not the images'
            raise ValueError(f"refiner: {self.path}: its output holds {bad} NaN or Inf value(s) on finite inputs "
                             f"(a broken model: export it again from a finite checkpoint)")
        out = np.clip(out.transpose(0, 2, 3, 1), 0.0, 1.0).astype(np.float32, copy=False)
        return out[0] if singles["coarse"] else out


class Choice(NamedTuple):
    """The candidate most similar to the real frame: its index (ties -> the lower index), its score, keep
    (score >= threshold; True without a threshold), and every candidate's score [K]."""

    index: int
    score: float
    keep: bool
    scores: np.ndarray


class ExaminerModel(_Model):
    """The exported Examiner: similarity of a candidate frame to a real reference frame, in [0, 1].

    ``score``/``choose`` take HWC images in [0, 1] of any size; those not of the model's ``size`` are
    resized to it with ``cv2.INTER_AREA`` (what the export's gates measured with). ``run`` takes the
    graph's NCHW arrays of exactly ``size``.
    """

    KIND = "examiner"

    def _setup(self, opened: _Opened) -> None:
        super()._setup(opened)
        path = opened.path
        if self.input_names != EXAMINER_INPUTS:
            raise FormatError(f"{path}: metadata {_key('inputs')!r}: expected {list(EXAMINER_INPUTS)}, got {list(self.input_names)}")
        if self.output_names != (EXAMINER_OUTPUT,):
            raise FormatError(f"{path}: metadata {_key('outputs')!r}: expected [{EXAMINER_OUTPUT!r}], got {list(self.output_names)}")
        if self.size[0] != self.size[1]:
            raise FormatError(f"{path}: metadata {_key('input_size')!r}: the Examiner takes square images, got {self.size}")
        if self.multiple is not None:
            raise FormatError(f"{path}: metadata {_key(SIZE_MULTIPLE_KEY)!r}: the Examiner takes one size, its "
                              f"{_key('input_size')!r} (it resizes its inputs to it)")
        _check_graph(opened.session, opened.header, path, ())

    def run(self, candidate: Any, reference: Any) -> np.ndarray:
        """The graph itself: float32 NCHW [B, 3, S, S] in [0, 1] (not normalised) -> scores [B]."""
        c = _check_nchw(candidate, "candidate", self.size)
        r = _check_nchw(reference, "reference", self.size)
        if c.shape[0] != r.shape[0]:
            raise ValueError(f"reference: batch {r.shape[0]} differs from candidate batch {c.shape[0]}")
        return self.session.run([EXAMINER_OUTPUT], {"candidate": c, "reference": r})[0]

    def _prepare(self, x: Any, name: str) -> np.ndarray:
        """HWC image(s) -> NCHW [B, 3, S, S] float32 at the model's size (cv2.INTER_AREA when resized)."""
        a, _ = _hwc_batch(x, name)
        H, W = self.size
        if tuple(a.shape[1:3]) != (H, W):
            import cv2

            a = np.stack([cv2.resize(np.ascontiguousarray(img), (W, H), interpolation=cv2.INTER_AREA) for img in a])
        return _nchw(a)

    def score(self, candidate: Any, reference: Any) -> np.ndarray:
        """HWC float images in [0, 1], [H, W, 3] or [B, H, W, 3] -> float32 scores [B] ([1] for single images).

        A single reference is used for every candidate of a batch (and vice versa). Images of another
        size than ``size`` are resized to it with cv2.INTER_AREA.
        """
        c, r = self._prepare(candidate, "candidate"), self._prepare(reference, "reference")
        if c.shape[0] != r.shape[0]:
            if r.shape[0] == 1:
                r = np.ascontiguousarray(np.broadcast_to(r, c.shape))
            elif c.shape[0] == 1:
                c = np.ascontiguousarray(np.broadcast_to(c, r.shape))
            else:
                raise ValueError(f"reference: batch {r.shape[0]} differs from candidate batch {c.shape[0]}")
        return self.session.run([EXAMINER_OUTPUT], {"candidate": c, "reference": r})[0].astype(np.float32, copy=False)

    def choose(self, candidates: Any, real: Any, threshold: float | None = None) -> Choice:
        """Score K candidates against the real frame in one batch and pick the best.

        candidates: [K, H, W, 3] or a sequence of K [H, W, 3]; real: [H, W, 3]. Ties go to the lower
        index; keep = score >= threshold (True when threshold is None); threshold must lie in [0, 1].
        """
        if threshold is not None and not 0.0 <= float(threshold) <= 1.0:
            raise ValueError(f"threshold: must lie in [0, 1] or be None, got {threshold}")
        if isinstance(candidates, Sequence) and not isinstance(candidates, np.ndarray):
            if len(candidates) == 0:
                raise ValueError("candidates: expected at least one candidate, got none")
            shapes = {np.shape(c) for c in candidates}
            if len(shapes) != 1 or len(next(iter(shapes))) != 3:
                raise ValueError(f"candidates: expected K images [H, W, 3] of one shape, got shapes {sorted(shapes)}")
            candidates = np.stack([_float_images(c, f"candidates[{i}]") for i, c in enumerate(candidates)])
        cands = _float_images(candidates, "candidates")
        if cands.ndim != 4 or cands.shape[0] < 1:
            raise ValueError(f"candidates: expected [K, H, W, 3] with K >= 1, got shape {list(cands.shape)}")
        real = _float_images(real, "real")
        if real.ndim != 3:
            raise ValueError(f"real: expected one image [H, W, 3], got shape {list(real.shape)}")
        scores = self.score(cands, real)
        index = int(np.argmax(scores))  # the first maximum: ties -> lower index
        score = float(scores[index])
        return Choice(index, score, True if threshold is None else bool(score >= threshold), scores)


_CLASSES: dict[str, type[_Model]] = {"refiner": RefinerModel, "examiner": ExaminerModel}


def load_model(path: str | os.PathLike, kind: str | None = None, **session_kw: Any) -> RefinerModel | ExaminerModel:
    """The model at ``path`` as a RefinerModel or ExaminerModel, by its ``trioman.kind`` metadata.

    ``kind`` ("refiner" / "examiner"), when given, must match the file (FormatError otherwise).
    ``session_kw``: ``optimization`` and ``threads`` as for the classes.
    """
    if kind is not None and kind not in KINDS:
        raise ValueError(f"kind: expected one of {KINDS} or None, got {kind!r}")
    opened = _open(path, session_kw.pop("optimization", "all"), session_kw.pop("threads", None))
    if session_kw:
        raise TypeError(f"load_model: unexpected keyword argument(s) {sorted(session_kw)}")
    if kind is not None and opened.header.kind != kind:
        raise FormatError(f"{opened.path}: metadata {_key('kind')!r}: expected {kind!r}, got {opened.header.kind!r}")
    return _CLASSES[opened.header.kind]._from_opened(opened)


__all__ = [
    "Choice",
    "ExaminerModel",
    "FORMAT",
    "FORMAT_VERSION",
    "META_PREFIX",
    "RefinerModel",
    "load_model",
    "crop_to",
    "pad_to_multiple",
    "padded_size",
    "read_metadata",
]
