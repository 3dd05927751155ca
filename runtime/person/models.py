"""The MediaPipe pose models as LiteRT interpreters: where the .tflite files are, their checks, one call each.

The files ship inside the ``mediapipe==0.10.21`` wheel (Apache-2.0), installed with ``--no-deps`` only to
carry them (docs/fit.md, "Per-frame person model"); mediapipe itself is never imported here (its Python
side needs protobuf < 7, which the rest of the project does not pin). ai-edge-litert (``trioman[fit]``)
runs them. Nothing is downloaded at run time.
"""

from __future__ import annotations

import contextlib
import hashlib
import importlib.metadata
import os
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator

import numpy as np

INSTALL_HINT = "pip install 'trioman[fit]' && pip install --no-deps mediapipe==0.10.21 (or: make install)"
MEDIAPIPE_VERSION = "0.10.21"
# Model name -> (path inside the mediapipe distribution, sha256 of the file in the 0.10.21 wheel). The
# constants of detector.py and landmarks.py belong to these exact weights.
MODEL_FILES = {
    "detector": ("mediapipe/modules/pose_detection/pose_detection.tflite",
                 "9ba9dd3d42efaaba86b4ff0122b06f29c4122e756b329d89dca1e297fd8f866c"),
    "landmarks": ("mediapipe/modules/pose_landmark/pose_landmark_full.tflite",
                  "e9a5c5cb17f736fafd4c2ec1da3b3d331d6edbe8a0d32395855aeb2cdfd64b9f"),
}
# Model name -> its input shape and its outputs by tensor name -> shape (the 0.10.21 files).
MODEL_INPUTS = {"detector": (1, 224, 224, 3), "landmarks": (1, 256, 256, 3)}
MODEL_OUTPUTS = {
    "detector": {"Identity": (1, 2254, 12), "Identity_1": (1, 2254, 1)},  # boxes + 4 keypoints, score logits
    # 39 x (x, y, z, visibility, presence) in crop pixels, the person flag, mask logits, heatmaps, world xyz
    "landmarks": {"Identity": (1, 195), "Identity_1": (1, 1), "Identity_2": (1, 256, 256, 1),
                  "Identity_3": (1, 64, 64, 39), "Identity_4": (1, 117)},
}


class MissingModelsError(OSError):
    """The pose models or their runtime are not installed; the message says what to install."""


def model_paths(root: Path | None = None) -> dict[str, Path]:
    """Model name -> .tflite path, from the installed mediapipe distribution (``root`` None) or from a folder
    holding ``pose_detection.tflite`` and ``pose_landmark_full.tflite``.

    Only the distribution's metadata is read: mediapipe is not imported. A missing file ->
    MissingModelsError naming it and the install line; a file with other bytes -> MissingModelsError too.
    """
    if root is None:
        try:
            dist = importlib.metadata.distribution("mediapipe")
        except importlib.metadata.PackageNotFoundError:
            raise MissingModelsError(f"person models: the mediapipe {MEDIAPIPE_VERSION} wheel that carries the pose "
                                     f"models is not installed: {INSTALL_HINT}") from None
        paths = {name: Path(str(dist.locate_file(rel))) for name, (rel, _) in MODEL_FILES.items()}
        where = f"mediapipe {dist.version}"
    else:
        paths = {name: Path(root) / Path(rel).name for name, (rel, _) in MODEL_FILES.items()}
        where = str(root)
    for name, path in paths.items():
        if not path.is_file():
            raise MissingModelsError(f"person models: {path.name} not found in {where} (the pose models ship in the "
                                     f"mediapipe {MEDIAPIPE_VERSION} wheel): {INSTALL_HINT}")
        digest = hashlib.sha256(path.read_bytes()).hexdigest()
        if digest != MODEL_FILES[name][1]:
            raise MissingModelsError(f"person models: {path}: not the file of mediapipe {MEDIAPIPE_VERSION} "
                                     f"(sha256 {digest[:12]}...): {INSTALL_HINT}")
    return paths


@contextlib.contextmanager
def _native_stderr_silenced() -> Iterator[None]:
    """File descriptor 2 pointed at /dev/null inside the block (native libraries' log lines); Python's own
    ``sys.stderr`` is flushed first and works again after it. Where fd 2 cannot be redirected, nothing changes."""
    sys.stderr.flush()
    try:
        saved = os.dup(2)
    except OSError:
        yield
        return
    try:
        with open(os.devnull, "wb") as null:
            os.dup2(null.fileno(), 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


class TfliteModel:
    """One .tflite file under LiteRT's interpreter (CPU, XNNPACK): ``model(x)`` -> outputs by tensor name."""

    def __init__(self, name: str, path: Path, threads: int) -> None:
        try:
            from ai_edge_litert.interpreter import Interpreter
        except ImportError:
            raise MissingModelsError(f"person models: ai-edge-litert, which runs them, is not installed: {INSTALL_HINT}") from None
        with _native_stderr_silenced():  # LiteRT announces its XNNPACK delegate on the C stderr, once per process
            self._interpreter: Any = Interpreter(model_path=str(path), num_threads=threads)
            self._interpreter.allocate_tensors()
        inputs = self._interpreter.get_input_details()
        outputs = {d["name"]: d for d in self._interpreter.get_output_details()}
        shapes = {k: tuple(int(s) for s in d["shape"]) for k, d in outputs.items()}
        if len(inputs) != 1 or tuple(inputs[0]["shape"]) != MODEL_INPUTS[name] or shapes != MODEL_OUTPUTS[name]:
            raise MissingModelsError(f"person models: {path}: unexpected tensors {shapes} (expected mediapipe "
                                     f"{MEDIAPIPE_VERSION}'s): {INSTALL_HINT}")
        self._input = inputs[0]["index"]
        self._outputs = {k: d["index"] for k, d in outputs.items()}

    def __call__(self, x: np.ndarray) -> dict[str, np.ndarray]:
        """``x`` float32 [1, S, S, 3] -> every output tensor by name (copies)."""
        self._interpreter.set_tensor(self._input, np.ascontiguousarray(x, np.float32))
        self._interpreter.invoke()
        return {k: self._interpreter.get_tensor(i).copy() for k, i in self._outputs.items()}


@dataclass
class PoseModels:
    """The pose detector and the full landmark model, loaded once per tracker."""

    detector: TfliteModel
    landmarks: TfliteModel


def load_models(root: Path | None = None, threads: int = 1) -> PoseModels:
    """Both models (``model_paths(root)``) under LiteRT with ``threads`` CPU threads each."""
    if not isinstance(threads, int) or isinstance(threads, bool) or threads < 1:
        raise ValueError(f"threads: must be an integer >= 1, got {threads!r}")
    paths = model_paths(root)
    return PoseModels(TfliteModel("detector", paths["detector"], threads),
                      TfliteModel("landmarks", paths["landmarks"], threads))


def check_image(image: Any, name: str = "image") -> np.ndarray:
    """``image`` as a uint8 RGB frame [H, W, 3] (H, W >= 2); ValueError naming ``name`` otherwise."""
    if not isinstance(image, np.ndarray):
        raise ValueError(f"{name}: expected a numpy uint8 array [H, W, 3], got {type(image).__name__}")
    if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3 or min(image.shape[:2]) < 2:
        shape = ", ".join(str(s) for s in image.shape)
        raise ValueError(f"{name}: expected uint8 [H, W, 3] with H, W >= 2, got {image.dtype} [{shape}]")
    return image
