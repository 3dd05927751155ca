"""The Refiner and Examiner behind one interface for online augmentation, loaded from a training run
folder, a checkpoint (.pt) or an exported ONNX file (.onnx).

Both sides take and return numpy HWC float32 images in [0, 1], as the runtime's ONNX wrappers
(``trioman.runtime.onnx_models``) do, so training and ``trioman augment`` feed the models the same way:

    refiner.refine(coarse [B, H, W, 3], reference [B, H, W, 3] | None, normal [B, H, W, 3] | None) -> [B, H, W, 3]
    examiner.score(candidates [B, H, W, 3], real [H, W, 3]) -> [B] scores in [0, 1]

``refiner.conditions`` says which inputs it reads ("none": coarse; "tex": + reference; "tex+geo":
+ normal). A torch Refiner, and an ONNX one exported with ``trioman.size_multiple``, takes images of any size: sides
that are not multiples of its total downsampling are padded (edge replicate, bottom and right) and the output
cropped back, with the runtime's ``pad_to_multiple`` / ``crop_to``; an older fixed-size ONNX Refiner takes its
export size only (``check_size``). The Examiner resizes to its own input size with cv2.INTER_AREA (as the runtime does). Errors name
the model's parameter (``refiner: ...``, ``examiner: ...``); the commands show their flags.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Protocol

import cv2
import numpy as np
import torch

from trioman.runtime.onnx_models import crop_to, pad_to_multiple
from trioman.toolkit.loops.checkpoint import SELECTED, latest_checkpoint


class PseudoExaminer(Protocol):
    def score(self, candidate: np.ndarray, reference: np.ndarray) -> np.ndarray: ...


def _nchw(x: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(np.ascontiguousarray(np.asarray(x, dtype=np.float32).transpose(0, 3, 1, 2)))


class TorchRefiner:
    """A trained torch Refiner with the runtime's ``refine`` signature (eval mode, no grad); any image size, sides
    padded to multiples of its total downsampling (``multiple``) and the output cropped back."""

    def __init__(self, model: torch.nn.Module, path: Path) -> None:
        self.model, self.path = model.eval(), path
        self.conditions: str = model.config.conditions
        self.multiple: int = model.total_downsample

    def check_size(self, height: int, width: int, name: str = "refiner") -> None:
        """ValueError naming ``name`` (the parameter or field that gave this Refiner) unless it takes ``height``
        x ``width`` images: any positive size."""
        if height < 1 or width < 1:
            raise ValueError(f"{name}: {self.path} (Refiner) takes images of a positive size, the training frames are "
                             f"{width}x{height} (W x H)")

    @torch.no_grad()
    def refine(self, coarse: np.ndarray, reference: np.ndarray | None = None, normal: np.ndarray | None = None) -> np.ndarray:
        size = np.shape(coarse)[1:3]
        args = [_nchw(pad_to_multiple(coarse, self.multiple))]
        args += [None if x is None else _nchw(pad_to_multiple(x, self.multiple)) for x in (reference, normal)]
        out = self.model(*args)[:, 0]  # [B, 3, H, W]: the refined coarse view
        return np.ascontiguousarray(crop_to(out.clamp(0, 1).permute(0, 2, 3, 1).numpy(), size))


class OnnxRefiner:
    """An exported Refiner (``trioman export onnx``): any image size with ``trioman.size_multiple``, else its export
    size only."""

    def __init__(self, path: Path) -> None:
        from trioman.runtime.onnx_models import load_model

        self.model, self.path = load_model(path, kind="refiner"), path
        self.conditions: str = self.model.conditions

    def check_size(self, height: int, width: int, name: str = "refiner") -> None:
        """ValueError naming ``name`` (the parameter or field that gave this Refiner) unless it takes ``height``
        x ``width`` images."""
        if not self.model.takes(height, width):
            h, w = self.model.size
            raise ValueError(f"{name}: {self.path} (Refiner ONNX) takes {w}x{h} (W x H) images, the training frames are "
                             f"{width}x{height}; export it at that size or train at another `image_scale`")

    def refine(self, coarse: np.ndarray, reference: np.ndarray | None = None, normal: np.ndarray | None = None) -> np.ndarray:
        return self.model.refine(coarse, reference=reference, normal=normal)


class TorchExaminer:
    """A trained torch Examiner with the runtime's ``score`` signature; images resized to its size."""

    def __init__(self, model: torch.nn.Module) -> None:
        self.model = model.eval()
        self.side: int = model.config.img_size

    def _prepare(self, x: np.ndarray) -> torch.Tensor:
        x = np.asarray(x, dtype=np.float32)
        x = x[None] if x.ndim == 3 else x
        if x.shape[1:3] != (self.side, self.side):
            x = np.stack([cv2.resize(np.ascontiguousarray(im), (self.side, self.side), interpolation=cv2.INTER_AREA)
                          for im in x])
        return _nchw(x)

    @torch.no_grad()
    def score(self, candidate: np.ndarray, reference: np.ndarray) -> np.ndarray:
        c, r = self._prepare(candidate), self._prepare(reference)
        if r.shape[0] == 1 and c.shape[0] > 1:
            r = r.expand_as(c)
        return self.model(c, r).numpy()


def _checkpoint_of(path: Path, kind: str) -> Path:
    """A run folder's checkpoint (an Examiner run's validated selected.pt first) or the file itself; ``kind``
    ("refiner" or "examiner") is also the name the error starts with."""
    if path.is_file():
        return path
    if kind == "examiner" and (path / SELECTED).is_file():
        return path / SELECTED
    ckpt = latest_checkpoint(path)
    if ckpt is None:
        raise FileNotFoundError(f"{kind}: {path} holds no checkpoint (expected a {kind} run folder, a .pt checkpoint "
                                f"or an exported .onnx)")
    return ckpt


def load_pseudo_refiner(refiner: str | os.PathLike) -> TorchRefiner | OnnxRefiner:
    """The Refiner at ``refiner``: a ``train-refiner`` run folder, one of its checkpoints, or an ONNX file."""
    from trioman.runtime.formats import FormatError
    from trioman.toolkit.refiner import load_refiner

    path = Path(refiner)
    if not path.exists():
        raise FileNotFoundError(f"refiner: not found: {path}")
    try:
        if path.suffix == ".onnx":
            return OnnxRefiner(path)
        ckpt = _checkpoint_of(path, "refiner")
        return TorchRefiner(load_refiner(ckpt), ckpt)
    except (FormatError, TypeError, KeyError) as err:
        raise ValueError(f"refiner: {path} is not a Refiner ({type(err).__name__}: {err})") from None
    except ValueError as err:
        raise ValueError(f"refiner: {err}") from None


def load_pseudo_examiner(examiner: str | os.PathLike) -> PseudoExaminer:
    """The Examiner at ``examiner``: a ``train-examiner`` run folder, one of its checkpoints, or an ONNX file."""
    from trioman.runtime.formats import FormatError
    from trioman.toolkit.examiner.loop import load_examiner

    path = Path(examiner)
    if not path.exists():
        raise FileNotFoundError(f"examiner: not found: {path}")
    try:
        if path.suffix == ".onnx":
            from trioman.runtime.onnx_models import load_model

            return load_model(path, kind="examiner")
        return TorchExaminer(load_examiner(_checkpoint_of(path, "examiner")))
    except (FormatError, TypeError, KeyError) as err:
        raise ValueError(f"examiner: {path} is not an Examiner ({type(err).__name__}: {err})") from None
    except ValueError as err:
        raise ValueError(f"examiner: {err}") from None
