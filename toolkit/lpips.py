"""LPIPS (Zhang et al. 2018, v0.1) with the AlexNet backbone, in plain torch (no torchvision): ``LPIPS``,
and its weights read from local files (``load_lpips``; ``TRIOMAN_LPIPS_DIR``, nothing is downloaded).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import NamedTuple

import torch
from torch import nn

ENV_VAR = "TRIOMAN_LPIPS_DIR"
BACKBONE_FILENAMES = ("alexnet.pth", "alexnet-owt-7be5be79.pth")
LIN_FILENAME = "alex.pth"
COMBINED_FILENAME = "lpips_alex.pth"
NOT_FOUND_MESSAGE = f"LPIPS not computed: weights not found (set {ENV_VAR})"

CHANNELS = (64, 192, 384, 256, 256)  # channels of the 5 taps
CONV_INDICES = (0, 3, 6, 8, 10)  # conv layers inside torchvision's alexnet.features
TAP_INDICES = (1, 4, 7, 9, 11)  # the ReLUs whose outputs are the taps
_SLICE_OF = {0: 1, 3: 2, 6: 3, 8: 4, 10: 5}  # lpips' net.slice{k} holding features[i]
# (out, in, k, stride, padding) of each conv, torchvision's AlexNet
CONV_SPECS = {
    0: (64, 3, 11, 4, 2),
    3: (192, 64, 5, 1, 2),
    6: (384, 192, 3, 1, 1),
    8: (256, 384, 3, 1, 1),
    10: (256, 256, 3, 1, 1),
}
SHIFT = (-0.030, -0.088, -0.188)
SCALE = (0.458, 0.448, 0.450)
MIN_SIZE = 31  # smallest H, W for which every AlexNet tap is non-empty

__all__ = [
    "ENV_VAR",
    "LPIPS",
    "LpipsWeightPaths",
    "NOT_FOUND_MESSAGE",
    "find_lpips_weights",
    "load_lpips",
    "load_lpips_state_dict",
]


class LPIPS(nn.Module):
    """LPIPS-AlexNet v0.1. ``forward(pred, gt)`` with [B, 3, H, W] images in [0, 1] -> distance [B].

    distance(x0, x1) = sum over the 5 AlexNet taps l of mean_{h,w} lin_l((n(f_l(x0)) - n(f_l(x1)))^2), where the
    inputs in [0, 1] are mapped to [-1, 1], then through the ScalingLayer ((x - ``SHIFT``) / ``SCALE``); f_l is
    the output of the l-th ReLU of AlexNet's ``features`` stack; n() divides each feature vector by its
    channel-wise L2 norm (+ 1e-10); lin_l is a learned 1x1 conv to one channel without bias: what
    ``lpips.LPIPS(net='alex')(x0, x1, normalize=True)`` computes.

    A fresh ``LPIPS()`` has random weights (for tests); use :meth:`from_files` / :func:`load_lpips`.
    The module is in eval mode and its parameters are frozen: no autograd graph is built unless an
    input requires grad, in which case the distance is differentiable w.r.t. the inputs (as a loss).
    """

    def __init__(self) -> None:
        super().__init__()
        layers: list[nn.Module] = []
        for i in range(12):
            if i in CONV_SPECS:
                o, c, k, s, p = CONV_SPECS[i]
                layers.append(nn.Conv2d(c, o, k, stride=s, padding=p))
            elif i in TAP_INDICES:
                layers.append(nn.ReLU(inplace=False))
            else:
                layers.append(nn.MaxPool2d(kernel_size=3, stride=2))
        self.features = nn.Sequential(*layers)  # same indices as torchvision's alexnet.features[:12]
        self.lins = nn.ModuleList(nn.Conv2d(c, 1, 1, bias=False) for c in CHANNELS)
        self.register_buffer("shift", torch.tensor(SHIFT).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("scale", torch.tensor(SCALE).view(1, 3, 1, 1), persistent=False)
        self.requires_grad_(False)
        self.eval()

    # ----------------------------------------------------------------------------------------- loading

    @classmethod
    def from_files(
        cls,
        backbone_path: str | os.PathLike,
        lin_path: str | os.PathLike | None = None,
        device: str | torch.device = "cpu",
    ) -> LPIPS:
        """Build from a backbone file and a lin file, or from one combined file (``lin_path`` None)."""
        model = cls()
        model.load_state_dict(load_lpips_state_dict(backbone_path, lin_path), strict=True)
        return model.to(device)

    @classmethod
    def from_dir(cls, folder: str | os.PathLike, device: str | torch.device = "cpu") -> LPIPS:
        """Build from a folder laid out as for ``TRIOMAN_LPIPS_DIR`` (:func:`find_lpips_weights`)."""
        paths = find_lpips_weights(folder)
        assert paths is not None
        return cls.from_files(paths.backbone, paths.lin, device=device)

    # ----------------------------------------------------------------------------------------- forward

    def taps(self, x: torch.Tensor) -> list[torch.Tensor]:
        """The 5 ReLU outputs of the AlexNet features for an already scaled input."""
        out = []
        for i, layer in enumerate(self.features):
            x = layer(x)
            if i in TAP_INDICES:
                out.append(x)
        return out

    def forward(self, pred: torch.Tensor, gt: torch.Tensor) -> torch.Tensor:
        """pred, gt: [B, 3, H, W] in [0, 1] (scaled to [-1, 1] here), H, W >= 31. -> [B]."""
        for name, x in (("pred", pred), ("gt", gt)):
            if not isinstance(x, torch.Tensor) or x.ndim != 4 or x.shape[1] != 3:
                shape = tuple(x.shape) if isinstance(x, torch.Tensor) else type(x).__name__
                raise ValueError(f"{name}: expected a tensor [B, 3, H, W] in [0, 1], got {shape}")
            if not x.is_floating_point():
                raise TypeError(f"{name}: expected a floating tensor in [0, 1], got dtype {x.dtype}")
            if x.shape[2] < MIN_SIZE or x.shape[3] < MIN_SIZE:
                raise ValueError(f"{name}: image {x.shape[2]}x{x.shape[3]} too small for LPIPS-AlexNet (need >= {MIN_SIZE})")
        if pred.shape != gt.shape:
            raise ValueError(f"pred and gt: shapes differ, {tuple(pred.shape)} vs {tuple(gt.shape)}")
        dtype = self.shift.dtype
        x = torch.cat((pred, gt)).to(dtype)
        x = (2.0 * x - 1.0 - self.shift) / self.scale
        B = pred.shape[0]
        total = x.new_zeros(B)
        for feat, lin in zip(self.taps(x), self.lins):
            n = feat / (torch.linalg.vector_norm(feat, dim=1, keepdim=True) + 1e-10)
            n0, n1 = n.split(B)
            total = total + lin((n0 - n1).square()).mean(dim=(1, 2, 3))
        return total


# --------------------------------------------------------------------------------------------------
# files


class LpipsWeightPaths(NamedTuple):
    backbone: Path  # the backbone file, or the combined file
    lin: Path | None  # None when ``backbone`` is a combined file


def _load_file(path: str | os.PathLike, what: str) -> dict[str, torch.Tensor]:
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"LPIPS {what} weights: file not found: {path}")
    try:
        obj = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # not a torch file, or a pickle that is not plain tensors
        msg = str(e)
        glob = [ln.strip() for ln in msg.splitlines() if "Unsupported global" in ln]
        if glob:  # a pickled object that is not plain tensors: say so briefly, not torch's long advice
            what_failed = glob[0].split(" Please use")[0]
            reason = f"refused by torch.load(weights_only=True), it holds more than tensors: {what_failed}"
        else:
            reason = f"not a torch state-dict file: {type(e).__name__}"
        raise ValueError(f"LPIPS {what} weights: {path} is not a loadable state dict ({reason})") from None
    if isinstance(obj, dict) and "state_dict" in obj and isinstance(obj["state_dict"], dict):
        obj = obj["state_dict"]
    if not isinstance(obj, dict):
        raise ValueError(
            f"LPIPS {what} weights: {path} holds a {type(obj).__name__}, expected a state dict (dict of tensors)"
        )
    out = {}
    for k, v in obj.items():
        k = str(k)
        if k.startswith("module."):
            k = k[len("module.") :]
        out[k] = v
    return out


def _backbone_candidates(i: int, p: str) -> tuple[str, ...]:
    s = _SLICE_OF[i]
    return (f"features.{i}.{p}", f"net.slice{s}.{i}.{p}", f"slice{s}.{i}.{p}")


def _lin_candidates(k: int) -> tuple[str, ...]:
    return (
        f"lin{k}.model.1.weight",
        f"lin{k}.model.0.weight",
        f"lins.{k}.model.1.weight",
        f"lins.{k}.model.0.weight",
        f"lins.{k}.weight",
    )


def _take(sd: dict, candidates: tuple[str, ...], shape: tuple[int, ...], path: Path, what: str) -> torch.Tensor:
    for key in candidates:
        if key in sd:
            v = sd[key]
            if not isinstance(v, torch.Tensor):
                raise ValueError(f"LPIPS {what} weights: {path}: key '{key}' holds a {type(v).__name__}, not a tensor")
            if tuple(v.shape) != shape:
                raise ValueError(
                    f"LPIPS {what} weights: {path}: key '{key}' has shape {tuple(v.shape)}, expected {shape}"
                )
            if not v.is_floating_point() or not torch.isfinite(v).all():
                raise ValueError(f"LPIPS {what} weights: {path}: key '{key}' is not a finite floating tensor")
            return v.float()
    found = ", ".join(sorted(sd)[:8]) + (", ..." if len(sd) > 8 else "")
    raise ValueError(
        f"LPIPS {what} weights: {path}: missing key '{candidates[0]}' "
        f"(also tried {', '.join(repr(c) for c in candidates[1:])}); keys found: [{found}]"
    )


def load_lpips_state_dict(
    backbone_path: str | os.PathLike, lin_path: str | os.PathLike | None = None
) -> dict[str, torch.Tensor]:
    """Read and validate the weight files -> a state dict in :class:`LPIPS`' own key layout.

    Files are data, loaded with ``weights_only=True``. Backbone: torchvision's AlexNet ImageNet state dict
    (keys ``features.{0,3,6,8,10}.{weight,bias}``, torchvision's download ``alexnet-owt-7be5be79.pth``;
    ``classifier.*`` is ignored) or the ``net.slice{k}.{i}.*`` keys of a saved ``lpips.LPIPS`` module. Lin
    layers: the ``lpips`` package's ``lpips/weights/v0.1/alex.pth`` (keys ``lin{k}.model.1.weight``,
    k = 0..4, shapes [1, C, 1, 1]); ``lin{k}.model.0.weight`` (no dropout), ``lins.{k}.model.{0,1}.weight``
    and this module's own ``lins.{k}.weight`` are accepted too. One combined file (``lin_path`` None: e.g. a
    saved ``LPIPS.state_dict()`` or ``lpips.LPIPS`` state dict) may hold both. A ``module.`` prefix and a
    ``{"state_dict": ...}`` wrapper are accepted."""
    bpath = Path(backbone_path)
    bsd = _load_file(bpath, "backbone" if lin_path is not None else "combined")
    if lin_path is None:
        lpath, lsd, lwhat = bpath, bsd, "combined"
    else:
        lpath = Path(lin_path)
        lsd, lwhat = _load_file(lpath, "lin"), "lin"
    bwhat = "backbone" if lin_path is not None else "combined"
    out: dict[str, torch.Tensor] = {}
    for i, (o, c, k, _, _) in CONV_SPECS.items():
        out[f"features.{i}.weight"] = _take(bsd, _backbone_candidates(i, "weight"), (o, c, k, k), bpath, bwhat)
        out[f"features.{i}.bias"] = _take(bsd, _backbone_candidates(i, "bias"), (o,), bpath, bwhat)
    for k, c in enumerate(CHANNELS):
        out[f"lins.{k}.weight"] = _take(lsd, _lin_candidates(k), (1, c, 1, 1), lpath, lwhat)
    return out


def find_lpips_weights(folder: str | os.PathLike | None = None) -> LpipsWeightPaths | None:
    """Locate the weight files in ``folder`` or, when None, in ``$TRIOMAN_LPIPS_DIR``.

    -> None when no folder is given and the variable is unset or empty (print ``NOT_FOUND_MESSAGE``).
    A folder that is named but does not hold the files is a FileNotFoundError naming what is missing
    (a misconfiguration should not silently drop the metric). Expected files: ``alexnet.pth`` (or
    torchvision's ``alexnet-owt-7be5be79.pth``) + ``alex.pth``, or one combined ``lpips_alex.pth``.
    """
    source = "folder"
    if folder is None:
        folder = os.environ.get(ENV_VAR, "").strip()
        source = ENV_VAR
        if not folder:
            return None
    root = Path(folder).expanduser()
    if not root.is_dir():
        raise FileNotFoundError(f"{source}: LPIPS weights folder not found: {root}")
    combined = root / COMBINED_FILENAME
    backbone = next((root / n for n in BACKBONE_FILENAMES if (root / n).is_file()), None)
    lin = root / LIN_FILENAME
    if backbone is not None and lin.is_file():
        return LpipsWeightPaths(backbone, lin)
    if combined.is_file():
        return LpipsWeightPaths(combined, None)
    missing = [] if backbone is not None else [" or ".join(BACKBONE_FILENAMES)]
    if not lin.is_file():
        missing.append(LIN_FILENAME)
    raise FileNotFoundError(
        f"{source}: {root} lacks the LPIPS weights: missing {', '.join(missing)} "
        f"(or one combined {COMBINED_FILENAME})"
    )


def load_lpips(folder: str | os.PathLike | None = None, device: str | torch.device = "cpu") -> LPIPS | None:
    """``find_lpips_weights(folder)`` then :meth:`LPIPS.from_files`; None when no weights are configured."""
    paths = find_lpips_weights(folder)
    if paths is None:
        return None
    return LPIPS.from_files(paths.backbone, paths.lin, device=device)


def load_lpips_or_say_why(command: str):
    """The LPIPS (AlexNet) model when its weights are available locally, else None after saying so once
    (``command: NOT_FOUND_MESSAGE``)."""
    model = load_lpips()
    if model is None:
        print(f"{command}: {NOT_FOUND_MESSAGE}")
    return model
