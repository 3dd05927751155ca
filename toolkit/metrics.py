"""Image metrics (torch): PSNR, SSIM, compositing, and the masked evaluation protocol.

Tensors are batched NCHW floats in [0, 1] (``[B, C, H, W]``); every metric returns one value per image
(``[B]``) and is differentiable. The protocol and SSIM's border conventions: docs/design.md, "Evaluation
protocol (4, after ExAvatar)".
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
import torch
import torch.nn.functional as F

from trioman.runtime.metrics import MSE_FLOOR, PSNR_MAX_DB

if TYPE_CHECKING:  # pragma: no cover
    from trioman.toolkit.lpips import LPIPS

SSIM_K1 = 0.01
SSIM_K2 = 0.03
SSIM_BORDERS = ("reflect", "valid")

__all__ = [
    "METRIC_KEYS",
    "PSNR_MAX_DB",
    "SSIM_BORDERS",
    "FrameMetrics",
    "composite_on",
    "evaluate_batch",
    "evaluate_pair",
    "gaussian_1d",
    "gaussian_window_size",
    "psnr",
    "ssim",
    "ssim_map",
]


# --------------------------------------------------------------------------------------------------
# input checks


def _check_images(x: Any, name: str) -> torch.Tensor:
    if not isinstance(x, torch.Tensor):
        raise TypeError(f"{name}: expected a torch.Tensor [B, C, H, W], got {type(x).__name__}")
    if x.ndim != 4:
        raise ValueError(f"{name}: expected shape [B, C, H, W], got {tuple(x.shape)}")
    if not x.is_floating_point():
        raise TypeError(f"{name}: expected a floating tensor with values in [0, 1], got dtype {x.dtype}")
    if x.numel() == 0:
        raise ValueError(f"{name}: empty tensor of shape {tuple(x.shape)}")
    bad = (~torch.isfinite(x)).sum().item()
    if bad:
        raise ValueError(f"{name}: {bad} non-finite values (NaN/Inf)")
    return x


def _check_pair(pred: Any, gt: Any) -> tuple[torch.Tensor, torch.Tensor]:
    pred = _check_images(pred, "pred")
    gt = _check_images(gt, "gt")
    if pred.shape != gt.shape:
        raise ValueError(f"pred and gt: shapes differ, {tuple(pred.shape)} vs {tuple(gt.shape)}")
    if gt.dtype != pred.dtype:
        gt = gt.to(pred.dtype)
    return pred, gt


def _check_mask(mask: Any, like: torch.Tensor, name: str = "mask") -> torch.Tensor:
    mask = _check_images(mask, name)
    B, C, H, W = like.shape
    if mask.shape[0] != B or mask.shape[2:] != (H, W) or mask.shape[1] not in (1, C):
        raise ValueError(f"{name}: expected shape [{B}, 1, {H}, {W}] (or [{B}, {C}, {H}, {W}]), got {tuple(mask.shape)}")
    lo, hi = mask.min().item(), mask.max().item()
    if lo < 0.0 or hi > 1.0:
        raise ValueError(f"{name}: values must lie in [0, 1], got range [{lo:.4g}, {hi:.4g}]")
    return mask.to(like.dtype)


# --------------------------------------------------------------------------------------------------
# PSNR


def psnr(pred: torch.Tensor, gt: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
    """Peak signal-to-noise ratio in dB with data_range 1, one value per image. -> [B]

    pred, gt: [B, C, H, W] in [0, 1]. ``mask`` ([B, 1, H, W] or [B, C, H, W], values in [0, 1]) makes
    the mean squared error a mask-weighted mean over the masked pixels (all channels) only; a mask
    that is all zero for some image is an error. Without a mask this is torchmetrics'
    ``PeakSignalNoiseRatio(data_range=1)`` computed per image. Identical images would give +inf:
    the MSE is floored at 1e-10, so the PSNR is capped at ``PSNR_MAX_DB`` = 100 dB (the cap has a zero
    gradient).
    """
    pred, gt = _check_pair(pred, gt)
    se = (pred - gt).square()
    if mask is None:
        mse = se.flatten(1).mean(dim=1)
    else:
        mask = _check_mask(mask, pred)
        weight = mask.expand_as(se)
        total = weight.flatten(1).sum(dim=1)
        empty = torch.nonzero(total <= 0).flatten().tolist()
        if empty:
            raise ValueError(f"mask: empty (all zero) for batch item(s) {empty}; PSNR over no pixels is undefined")
        mse = (se * weight).flatten(1).sum(dim=1) / total
    return 10.0 * torch.log10(1.0 / mse.clamp_min(MSE_FLOOR))


# --------------------------------------------------------------------------------------------------
# SSIM


def gaussian_window_size(sigma: float) -> int:
    """The Gaussian window torchmetrics and skimage use for ``sigma``: 2 * int(3.5 sigma + 0.5) + 1."""
    return 2 * int(3.5 * sigma + 0.5) + 1


def gaussian_1d(window: int, sigma: float, dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    """[window] normalised Gaussian taps centred on the middle one."""
    x = torch.arange(window, dtype=torch.float64) - (window - 1) / 2.0
    g = torch.exp(-0.5 * (x / sigma) ** 2)
    return (g / g.sum()).to(dtype=dtype, device=device)


def ssim_map(
    pred: torch.Tensor,  # [B, C, H, W]
    gt: torch.Tensor,  # [B, C, H, W]
    window: int | None = 11,
    sigma: float = 1.5,
    border: str = "reflect",
) -> torch.Tensor:
    """Per-pixel, per-channel SSIM (Gaussian window, K1 0.01, K2 0.03, data_range 1).

    -> [B, C, H, W] for ``border="reflect"`` (reflect padding by the window radius, torchmetrics >= 1.5),
    [B, C, H - window + 1, W - window + 1] for ``border="valid"`` (no padding; torchmetrics <= 1.4 and
    skimage). ``window`` None derives it from sigma (11 for 1.5), as torchmetrics does. The border
    conventions: docs/design.md, "Evaluation protocol (4, after ExAvatar)". Differentiable and finite for any finite input (constant,
    all-black and all-white images give 1 for identical images, the denominators are >= C1 * C2).
    """
    pred, gt = _check_pair(pred, gt)
    if not (isinstance(sigma, (int, float)) and math.isfinite(sigma) and sigma > 0):
        raise ValueError(f"sigma: must be a positive number, got {sigma!r}")
    if window is None:
        window = gaussian_window_size(sigma)
    if not isinstance(window, (int, np.integer)) or window < 1 or window % 2 == 0:
        raise ValueError(f"window: must be a positive odd integer, got {window!r}")
    window = int(window)
    if border not in SSIM_BORDERS:
        raise ValueError(f"border: must be one of {SSIM_BORDERS}, got {border!r}")
    B, C, H, W = pred.shape
    r = (window - 1) // 2
    if border == "reflect":
        if r >= H or r >= W:  # torch reflect padding needs pad < size
            raise ValueError(f"pred: image {H}x{W} too small for SSIM window {window} with reflect borders (need > {r})")
        pred = F.pad(pred, (r, r, r, r), mode="reflect")
        gt = F.pad(gt, (r, r, r, r), mode="reflect")
    elif H < window or W < window:
        raise ValueError(f"pred: image {H}x{W} smaller than the SSIM window {window} (border='valid')")

    # Local moments of images centred on their per-channel means: (co)variances are shift invariant,
    # and centring removes most of the float32 cancellation in E[x^2] - E[x]^2 (a constant image
    # gets exactly zero variance, so identical constant images give exactly 1).
    m_p = pred.mean(dim=(2, 3), keepdim=True).detach()
    m_g = gt.mean(dim=(2, 3), keepdim=True).detach()
    pc, gc = pred - m_p, gt - m_g
    g = gaussian_1d(window, float(sigma), pred.dtype, pred.device)
    stack = torch.cat((pc, gc, pc * pc, gc * gc, pc * gc))  # [5B, C, H', W']
    stack = F.conv2d(stack, g.view(1, 1, window, 1).expand(C, 1, window, 1), groups=C)
    stack = F.conv2d(stack, g.view(1, 1, 1, window).expand(C, 1, 1, window), groups=C)
    d_p, d_g, e_pp, e_gg, e_pg = stack.split(B)

    c1 = (SSIM_K1 * 1.0) ** 2
    c2 = (SSIM_K2 * 1.0) ** 2
    mu_p, mu_g = d_p + m_p, d_g + m_g
    var_p = (e_pp - d_p * d_p).clamp_min(0.0)
    var_g = (e_gg - d_g * d_g).clamp_min(0.0)
    cov = e_pg - d_p * d_g
    return ((2.0 * mu_p * mu_g + c1) * (2.0 * cov + c2)) / ((mu_p * mu_p + mu_g * mu_g + c1) * (var_p + var_g + c2))


def ssim(
    pred: torch.Tensor,  # [B, C, H, W]
    gt: torch.Tensor,  # [B, C, H, W]
    window: int | None = 11,
    sigma: float = 1.5,
    border: str = "reflect",
) -> torch.Tensor:
    """Mean SSIM per image -> [B]. Defaults = torchmetrics' StructuralSimilarityIndexMeasure(data_range=1)
    (version >= 1.5; ``border="valid"`` for <= 1.4 and skimage). The loss is ``1 - ssim(pred, gt)``."""
    return ssim_map(pred, gt, window=window, sigma=sigma, border=border).flatten(1).mean(dim=1)


# --------------------------------------------------------------------------------------------------
# compositing


def composite_on(img, mask, color=1.0):
    """``img * mask + color * (1 - mask)``: put the masked foreground on a flat background.

    torch: img [B, C, H, W] (or [C, H, W]), mask broadcastable to it ([B, 1, H, W]); numpy (HWC):
    img [H, W, C] (or [B, H, W, C]), mask [H, W] or [H, W, 1]. ``color`` is a scalar (1.0 = white)
    or one value per channel.
    """
    if isinstance(img, torch.Tensor):
        if not isinstance(mask, torch.Tensor):
            raise TypeError(f"mask: expected a torch.Tensor like img, got {type(mask).__name__}")
        if img.ndim not in (3, 4):
            raise ValueError(f"img: expected [B, C, H, W] or [C, H, W], got {tuple(img.shape)}")
        if mask.ndim == img.ndim - 1:
            mask = mask.unsqueeze(-3)  # [B, H, W] / [H, W] -> channel axis added
        if mask.ndim != img.ndim or mask.shape[-2:] != img.shape[-2:]:
            raise ValueError(f"mask: shape {tuple(mask.shape)} does not match img {tuple(img.shape)}")
        mask = mask.to(dtype=img.dtype, device=img.device)
        c = torch.as_tensor(color, dtype=img.dtype, device=img.device)
        if c.ndim == 1:
            if c.numel() != img.shape[-3]:
                raise ValueError(f"color: {c.numel()} values for {img.shape[-3]} channels")
            c = c.view(-1, 1, 1)
        elif c.ndim != 0:
            raise ValueError(f"color: expected a scalar or one value per channel, got shape {tuple(c.shape)}")
        return img * mask + c * (1.0 - mask)
    img = np.asarray(img)
    mask = np.asarray(mask)
    if img.ndim not in (3, 4):
        raise ValueError(f"img: expected [H, W, C] or [B, H, W, C], got {img.shape}")
    if mask.ndim == img.ndim - 1:
        mask = mask[..., None]
    if mask.ndim != img.ndim or mask.shape[-3:-1] != img.shape[-3:-1]:
        raise ValueError(f"mask: shape {mask.shape} does not match img {img.shape}")
    dtype = img.dtype if np.issubdtype(img.dtype, np.floating) else np.float32
    c = np.asarray(color, dtype=dtype)
    if c.ndim == 1 and c.shape[0] != img.shape[-1]:
        raise ValueError(f"color: {c.shape[0]} values for {img.shape[-1]} channels")
    if c.ndim > 1:
        raise ValueError(f"color: expected a scalar or one value per channel, got shape {c.shape}")
    mask = mask.astype(dtype, copy=False)
    return (img * mask + c * (1.0 - mask)).astype(dtype, copy=False)


# --------------------------------------------------------------------------------------------------
# evaluation protocol

METRIC_KEYS = ("psnr", "ssim", "lpips", "psnr_unmasked", "ssim_unmasked", "lpips_unmasked")


def evaluate_batch(
    pred: torch.Tensor,  # [B, 3, H, W]
    gt: torch.Tensor,  # [B, 3, H, W]
    gt_mask: torch.Tensor,  # [B, 1, H, W]
    lpips: LPIPS | None = None,
    background: float | Sequence[float] = 1.0,
    ssim_border: str = "reflect",
) -> dict[str, torch.Tensor | None]:
    """The masked protocol on a batch -> {key: [B] tensor or None}, keys ``METRIC_KEYS``.

    'psnr', 'ssim', 'lpips': both pred and gt composited with the GT mask on ``background`` (white);
    '*_unmasked': the raw images. 'lpips*' are None when no LPIPS model is given ('not computed').
    Computed without autograd.
    """
    pred, gt = _check_pair(pred, gt)
    gt_mask = _check_mask(gt_mask, pred, "gt_mask")
    with torch.no_grad():
        pred_m = composite_on(pred, gt_mask, background)
        gt_m = composite_on(gt, gt_mask, background)
        out: dict[str, torch.Tensor | None] = {
            "psnr": psnr(pred_m, gt_m),
            "ssim": ssim(pred_m, gt_m, border=ssim_border),
            "lpips": None,
            "psnr_unmasked": psnr(pred, gt),
            "ssim_unmasked": ssim(pred, gt, border=ssim_border),
            "lpips_unmasked": None,
        }
        if lpips is not None:
            out["lpips"] = lpips(pred_m, gt_m)
            out["lpips_unmasked"] = lpips(pred, gt)
    return out


def _frame_to_tensor(x: Any, name: str, channels: int | None, device: torch.device | None) -> torch.Tensor:
    """One frame -> [1, C, H, W] float32. numpy is HWC (project convention); torch is CHW or 1CHW."""
    if isinstance(x, np.ndarray):
        if not np.issubdtype(x.dtype, np.floating):
            raise TypeError(f"{name}: expected float values in [0, 1], got dtype {x.dtype} (divide uint8 by 255)")
        if channels is None:  # a mask: [H, W] or [H, W, 1]
            if x.ndim == 3 and x.shape[2] == 1:
                x = x[..., 0]
            if x.ndim != 2:
                raise ValueError(f"{name}: expected a mask [H, W] or [H, W, 1], got {x.shape}")
            t = torch.from_numpy(np.ascontiguousarray(x, dtype=np.float32))[None, None]
        else:
            if x.ndim != 3 or x.shape[2] != channels:
                raise ValueError(f"{name}: expected an image [H, W, {channels}] (numpy HWC), got {x.shape}")
            t = torch.from_numpy(np.ascontiguousarray(x, dtype=np.float32)).permute(2, 0, 1)[None]
    elif isinstance(x, torch.Tensor):
        t = x.float()
        if channels is None:
            while t.ndim < 4:
                t = t.unsqueeze(0)
            if t.shape[:2] != (1, 1):
                raise ValueError(f"{name}: expected a mask [H, W], [1, H, W] or [1, 1, H, W], got {tuple(x.shape)}")
        else:
            if t.ndim == 3:
                t = t.unsqueeze(0)
            if t.ndim != 4 or t.shape[:2] != (1, channels):
                raise ValueError(f"{name}: expected [{channels}, H, W] or [1, {channels}, H, W], got {tuple(x.shape)}")
    else:
        raise TypeError(f"{name}: expected a numpy array or torch tensor, got {type(x).__name__}")
    return t.to(device) if device is not None else t


def evaluate_pair(
    pred,
    gt,
    gt_mask,
    lpips: LPIPS | None = None,
    background: float | Sequence[float] = 1.0,
    ssim_border: str = "reflect",
) -> dict[str, float | None]:
    """Metrics of one frame under the masked protocol -> {key: float or None}, keys ``METRIC_KEYS``.

    pred, gt: numpy [H, W, 3] float in [0, 1] (HWC, the project's image convention) or torch [3, H, W]
    / [1, 3, H, W]; gt_mask: numpy [H, W] / [H, W, 1] or torch [H, W] / [1, H, W] / [1, 1, H, W], in
    [0, 1]. 'lpips' and 'lpips_unmasked' are None when ``lpips`` is None (not computed).
    """
    device = None
    if lpips is not None:
        p = next(lpips.parameters(), None)
        device = p.device if p is not None else None
    if device is None and isinstance(pred, torch.Tensor):
        device = pred.device
    p = _frame_to_tensor(pred, "pred", 3, device)
    g = _frame_to_tensor(gt, "gt", 3, device)
    m = _frame_to_tensor(gt_mask, "gt_mask", None, device)
    out = evaluate_batch(p, g, m, lpips=lpips, background=background, ssim_border=ssim_border)
    return {k: (None if v is None else float(v[0].item())) for k, v in out.items()}


class FrameMetrics:
    """Per-frame metrics accumulator: ``add`` frames, ``summary`` averages them (the protocol's mean).

    >>> fm = FrameMetrics(lpips=None)
    >>> fm.add(pred, gt, gt_mask)            # one frame (see evaluate_pair for the accepted layouts)
    >>> fm.summary()                         # {'frames': n, 'psnr': ..., 'lpips': None, ...}
    """

    def __init__(
        self,
        lpips: LPIPS | None = None,
        background: float | Sequence[float] = 1.0,
        ssim_border: str = "reflect",
    ) -> None:
        if ssim_border not in SSIM_BORDERS:
            raise ValueError(f"ssim_border: must be one of {SSIM_BORDERS}, got {ssim_border!r}")
        self.lpips = lpips
        self.background = background
        self.ssim_border = ssim_border
        self.frames: list[dict[str, Any]] = []

    def add(self, pred, gt, gt_mask, name: str | None = None) -> dict[str, float | None]:
        """Evaluate one frame, record it (with ``name`` when given) and return its metrics."""
        row = evaluate_pair(pred, gt, gt_mask, lpips=self.lpips, background=self.background, ssim_border=self.ssim_border)
        self.frames.append({"name": name, **row})
        return row

    def add_batch(self, pred: torch.Tensor, gt: torch.Tensor, gt_mask: torch.Tensor, names=None) -> None:
        """Evaluate a batch [B, 3, H, W] (mask [B, 1, H, W]); records B frames."""
        out = evaluate_batch(pred, gt, gt_mask, lpips=self.lpips, background=self.background, ssim_border=self.ssim_border)
        B = pred.shape[0]
        if names is not None and len(names) != B:
            raise ValueError(f"names: {len(names)} names for a batch of {B}")
        for i in range(B):
            row = {k: (None if v is None else float(v[i].item())) for k, v in out.items()}
            self.frames.append({"name": None if names is None else names[i], **row})

    def __len__(self) -> int:
        return len(self.frames)

    def summary(self) -> dict[str, float | int | None]:
        """{'frames': n, key: mean over frames (None when not computed)} for every key in METRIC_KEYS."""
        if not self.frames:
            raise ValueError("FrameMetrics: no frames added; nothing to average")
        out: dict[str, float | int | None] = {"frames": len(self.frames)}
        for k in METRIC_KEYS:
            vals = [f[k] for f in self.frames]
            out[k] = None if any(v is None for v in vals) else float(np.mean(vals))
        return out
