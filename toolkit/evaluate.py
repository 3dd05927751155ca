"""Evaluate a trained avatar on a subject split: metrics (ExAvatar's masked protocol and unmasked),
per-frame CSV, summary JSON, markdown table, a GT | render | error grid and a video."""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path

import cv2
import numpy as np
import torch
from tqdm import tqdm

from trioman.runtime.formats import Subject, load_subject
from trioman.runtime.image_io import write_png, write_video
from trioman.runtime.outputs import atomic_write_text, check_not_input, kind_of
from trioman.runtime.preview import contact_sheet
from trioman.toolkit.avatar.model import GaussianAvatar, PoseFree
from trioman.toolkit.cpu import flush_denormals
from trioman.toolkit.evaluate_config import POSES, PROTOCOLS, EvalOptions
from trioman.toolkit.metrics import METRIC_KEYS, evaluate_pair
from trioman.toolkit.loops.checkpoint import latest_checkpoint, load_checkpoint
from trioman.toolkit.train.config import TrainConfig
from trioman.toolkit.pose_refit import RefitSettings, refit_poses
from trioman.toolkit.train.loop import photometric, render
from trioman.toolkit.train.resume import read_record

WHITE = torch.ones(3)
# --protocol exavatar: ExAvatar's evaluation (ExAvatar_RELEASE avatar/tools/eval_neuman.py without --include_bkg;
# the release holds no X-Humans evaluation script, so X-Humans is scored the same way): both images composited over
# white outside the GT mask, full image, no crop, torchmetrics PSNR and SSIM (data range 1), LPIPS-AlexNet
# on [-1, 1], mean over frames. Its SSIM depends on the torchmetrics release (see trioman.toolkit.metrics):
# both are reported, ">= 1.5" (the reflect-padded border, also our 'ssim') and "<= 1.4" (the valid region).
EXAVATAR_KEYS = ("exavatar_psnr", "exavatar_ssim", "exavatar_ssim_tm14", "exavatar_lpips")


def load_run(run: str | Path, checkpoint: str | Path | None = None) -> tuple[GaussianAvatar, Subject, TrainConfig, int]:
    """The trained avatar of a run folder (its latest checkpoint unless one is named)."""
    run = Path(run)
    cfg_file = run / "config.json"
    if not cfg_file.is_file():
        raise FileNotFoundError(f"{run}: not a run folder (no config.json)")
    saved = read_record(run)
    cfg = TrainConfig.from_dict(saved["train"])
    ckpt = Path(checkpoint) if checkpoint else latest_checkpoint(run)
    if ckpt is None:
        raise FileNotFoundError(f"{run}: no finished checkpoint yet (train it, or resume with trioman train --resume)")
    subject = load_subject(saved["subject"])
    model = GaussianAvatar(subject.body, cfg.avatar)
    state = load_checkpoint(ckpt)
    model.load_state_dict(state["model"])
    model.eval()
    return model, subject, cfg, int(state["step"])


def run_poses(run: str | Path, subject: Subject, checkpoint: str | Path | None = None) -> tuple[np.ndarray, np.ndarray] | None:
    """The subject's poses [F, J, 3] and roots [F, 3] as the run learnt to correct them (``--refine-poses``), from
    its latest checkpoint unless one is named; None when the run learnt no corrections."""
    from trioman.toolkit.train.pose_corrections import PoseCorrections

    run = Path(run)
    cfg = TrainConfig.from_dict(read_record(run)["train"])
    if not cfg.refine_poses:
        return None
    ckpt = Path(checkpoint) if checkpoint else latest_checkpoint(run)
    if ckpt is None:
        raise FileNotFoundError(f"{run}: no finished checkpoint yet (train it, or resume with trioman train --resume)")
    state = load_checkpoint(ckpt)
    if "pose_corrections" not in state:
        raise ValueError(f"{ckpt}: a run trained with refine_poses but its checkpoint holds no pose_corrections")
    corrections = PoseCorrections(subject.sequence, subject.num_joints, cfg.pose_knot_every)
    corrections.load_state_dict(state["pose_corrections"])
    return corrections.all(subject.poses, subject.trans)


@torch.no_grad()
def render_frame(model: GaussianAvatar, subject: Subject, i: int, background: torch.Tensor = WHITE,
                 poses: tuple[np.ndarray, np.ndarray] | None = None, pose_free: PoseFree | None = None) -> np.ndarray:
    """The avatar (refined set) at frame i's pose and camera, full resolution; ``poses``: (poses [F, J, 3], roots
    [F, 3]) to take frame i's from instead of the subject's stored ones; ``pose_free``: ``model.pose_free()``, for
    many frames. -> [H, W, 3] float32."""
    pose, trans = (subject.poses, subject.trans) if poses is None else poses
    out = model(torch.from_numpy(np.array(pose[i])), torch.from_numpy(np.array(trans[i])), pose_free)
    img = render(out.refined, torch.from_numpy(np.array(subject.viewmat[i])), torch.from_numpy(np.array(subject.K[i])),
                 subject.width, subject.height, background)
    return img.clamp(0, 1).numpy()


def error_map(pred: np.ndarray, gt: np.ndarray, gain: float = 4.0) -> np.ndarray:
    """Per-pixel mean absolute error as an inferno heat map (x gain, clipped). -> [H, W, 3]."""
    err = np.clip(np.abs(pred - gt).mean(-1) * gain, 0, 1)
    bgr = cv2.applyColorMap((err * 255).astype(np.uint8), cv2.COLORMAP_INFERNO)
    return bgr[..., ::-1].astype(np.float32) / 255


def poses_key(poses: str, refit: RefitSettings | None = None) -> str:
    """What an evaluation at ``poses`` rendered, as a reuse check compares it: the option, and for "optimised" the
    refit's method and settings (``refit`` None: the defaults)."""
    if poses != "optimised":
        return poses
    r = refit or RefitSettings()
    return f"optimised (L-BFGS, at most {r.steps} steps, penalty {r.penalty:g}, scale {r.scale:g})"


@flush_denormals()
def evaluate(run: str | Path, split: str = EvalOptions.split, out: str | Path | None = None, lpips=None,
             progress: bool = True, grid_frames: int = 6, video: bool = EvalOptions.video,
             protocol: str = EvalOptions.protocol, poses: str = EvalOptions.poses, refit: RefitSettings | None = None) -> dict:
    """Evaluate and write the report into ``out`` (default RUN/eval_<split>). Returns the summary.

    ``protocol="exavatar"`` adds ExAvatar's numbers (``EXAVATAR_KEYS``) beside ours. ``poses``: "run" renders at
    the subject's stored poses as the run corrected them (``refine_poses``; the stored ones when it learnt none),
    "stored" at the stored ones as they are, "true" at the recorded ground-truth poses (synthetic subjects with
    --pose-noise), so the metric measures the avatar and not the noise of the stored test poses, "optimised" at the
    run's poses refitted to each frame's own pixels with the avatar frozen (``refit``; fitted videos, whose test
    poses carry the fit's error)."""
    if protocol not in PROTOCOLS:
        raise ValueError(f"protocol: expected one of {list(PROTOCOLS)}, got {protocol!r}")
    if poses not in POSES:
        raise ValueError(f"poses: expected one of {list(POSES)}, got {poses!r}")
    model, subject, cfg, step = load_run(run)
    out = Path(out) if out else Path(run) / f"eval_{split}"
    try:  # the report goes beside what it measures, never into the subject (nor another output)
        check_not_input(out, [subject.root])
    except ValueError as err:
        raise ValueError(f"out: {err}") from None
    other = kind_of(out)
    if other is not None:
        raise ValueError(f"out: {out} is a trioman {other.name} folder; write the report to another folder")
    if poses == "true" and subject.poses_true is None:
        raise ValueError(f"poses: {subject.root} records no ground-truth poses (poses_true); evaluate at the stored poses")
    requested = poses
    corrected = run_poses(run, subject) if poses in ("run", "optimised") else None
    at = {"run": corrected, "stored": None, "true": (subject.poses_true, subject.trans), "optimised": corrected}[poses]
    if poses == "run":
        poses = "stored" if at is None else "stored, corrected by the run"
    elif poses == "optimised":
        refit = refit or RefitSettings()
        start = (subject.poses, subject.trans) if at is None else at
        bar = tqdm(total=len(subject.indices(split)), desc=f"refit {split} poses", unit="frame",
                   disable=None if progress else True)
        at = refit_poses(model, subject, split, *start, lambda img, gt: photometric(img, gt, cfg), render, refit,
                         lambda k: bar.update(k - bar.n))
        bar.close()
        poses = (f"{'stored' if corrected is None else 'stored, corrected by the run'}, refitted to each frame "
                 f"(L-BFGS, at most {refit.steps} steps, at {'full size' if refit.scale == 1 else f'{refit.scale:g} of the size'})")
    out.mkdir(parents=True, exist_ok=True)
    idx = subject.indices(split)
    if len(idx) == 0:
        raise ValueError(f"split: subject {subject.root} has no {split!r} frames")
    rows, triplets = [], []
    picks = set(idx[np.linspace(0, len(idx) - 1, min(grid_frames, len(idx))).astype(int)].tolist())
    with torch.no_grad():
        pose_free = model.pose_free()
    for i in tqdm(idx, desc=f"eval {split}", unit="frame", disable=None if progress else True):
        pred = render_frame(model, subject, int(i), poses=at, pose_free=pose_free)
        mask = subject.mask(int(i))
        gt = subject.image(int(i)) + (1 - mask)[..., None]  # premultiplied GT over white
        m = evaluate_pair(pred, gt, mask, lpips=lpips)
        if protocol == "exavatar":
            valid = evaluate_pair(pred, gt, mask, ssim_border="valid")
            m = {**m, "exavatar_psnr": m["psnr"], "exavatar_ssim": m["ssim"], "exavatar_ssim_tm14": valid["ssim"],
                 "exavatar_lpips": m["lpips"]}
        rows.append({"frame": subject.frame_names[i], "sequence": subject.sequence[i], **m})
        triplets.append((gt, pred))
        if int(i) in picks:
            triplets[-1] = (gt, pred, error_map(pred, gt))
    # "poses" says what the frames were rendered at; "poses_key" is the option asked for (a reuse check compares it)
    summary = {**_summarise(rows, split, step, cfg, lpips is not None, protocol), "poses": poses,
               "poses_key": poses_key(requested, refit)}
    _write_reports(out, rows, summary)
    grid = [im for t in triplets if len(t) == 3 for im in t]
    labels = [f"{name} {r['frame']}" for r, t in zip(rows, triplets) if len(t) == 3 for name in ("GT", "render", "error x4")]
    write_png(out / "grid.png", contact_sheet(grid, labels, cols=3))
    if video:
        write_video(out / "video.mp4", (np.concatenate(t[:2], axis=1) for t in triplets), fps=12)
    return summary


@flush_denormals()
def comparison_grid(runs: dict[str, str | Path], split: str, out: str | Path, frames: int = 4) -> Path:
    """One row per frame of ``frames`` evenly spaced ``split`` frames: the ground truth (over white), then each run's
    render at its own poses (``runs``: label -> run folder, all on one subject), captioned with its masked PSNR.
    Written as a PNG to ``out``; -> ``out``."""
    loaded = {name: load_run(run) for name, run in runs.items()}
    subjects = {str(Path(s.root).resolve()) for _, s, _, _ in loaded.values()}
    if len(subjects) != 1:
        raise ValueError(f"runs: must share one subject, got {sorted(subjects)}")
    subject = next(iter(loaded.values()))[1]
    idx = subject.indices(split)
    if len(idx) == 0:
        raise ValueError(f"split: subject {subject.root} has no {split!r} frames")
    picks = idx[np.linspace(0, len(idx) - 1, min(frames, len(idx))).astype(int)]
    poses = {name: run_poses(runs[name], subject) for name in runs}
    images, labels = [], []
    for i in picks.tolist():
        mask = subject.mask(i)
        gt = subject.image(i) + (1 - mask)[..., None]
        images.append(gt)
        labels.append(f"GT {subject.frame_names[i]}")
        for name, (model, _, _, _) in loaded.items():
            pred = render_frame(model, subject, i, poses=poses[name])
            images.append(pred)
            labels.append(f"{name} {evaluate_pair(pred, gt, mask)['psnr']:.2f} dB")
    out = Path(out)
    write_png(out, contact_sheet(images, labels, cols=1 + len(runs)))
    return out


def _summarise(rows: list[dict], split: str, step: int, cfg: TrainConfig, has_lpips: bool, protocol: str) -> dict:
    def mean(rs: list[dict], key: str):
        vals = [r[key] for r in rs if r[key] is not None]
        return float(np.mean(vals)) if vals else None

    by_seq = {}
    for name in dict.fromkeys(r["sequence"] for r in rows):
        rs = [r for r in rows if r["sequence"] == name]
        by_seq[name] = {"frames": len(rs), **{k: mean(rs, k) for k in METRIC_KEYS}}
    summary = {
        "split": split, "step": step, "preset": cfg.preset, "frames": len(rows),
        "lpips": "AlexNet" if has_lpips else "not computed (no local weights; set TRIOMAN_LPIPS_DIR)",
        "mean": {k: mean(rows, k) for k in METRIC_KEYS}, "sequences": by_seq,
    }
    if protocol == "exavatar":
        summary["exavatar"] = {k.removeprefix("exavatar_"): mean(rows, k) for k in EXAVATAR_KEYS}
    return summary


def _fmt(v) -> str:
    return "n/a" if v is None else f"{v:.4f}" if abs(v) < 1 else f"{v:.2f}"


def _write_reports(out: Path, rows: list[dict], summary: dict) -> None:
    buf = io.StringIO()
    extra = list(EXAVATAR_KEYS) if "exavatar" in summary else []
    writer = csv.DictWriter(buf, fieldnames=["frame", "sequence", *METRIC_KEYS, *extra], lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    atomic_write_text(out / "metrics.csv", buf.getvalue())
    atomic_write_text(out / "summary.json", json.dumps(summary, indent=2) + "\n")
    lines = [
        f"# Evaluation: {summary['split']} split, step {summary['step']} ({summary['preset']} preset)",
        "",
        "PSNR/SSIM/LPIPS: prediction and GT composited with the GT mask on white (ExAvatar's protocol);",
        f"'unmasked': both on white without the mask. LPIPS: {summary['lpips']}.",
        "",
        "| sequence | frames | PSNR | SSIM | LPIPS | PSNR unmasked | SSIM unmasked |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, s in [*summary["sequences"].items(), ("**all**", {"frames": summary["frames"], **summary["mean"]})]:
        lines.append(f"| {name} | {s['frames']} | {_fmt(s['psnr'])} | {_fmt(s['ssim'])} | {_fmt(s['lpips'])} | "
                     f"{_fmt(s['psnr_unmasked'])} | {_fmt(s['ssim_unmasked'])} |")
    if "exavatar" in summary:
        e = summary["exavatar"]
        lines += ["", "## ExAvatar's protocol", "",
                  "Both images composited over white outside the GT mask, full image, no crop, PSNR and SSIM with data",
                  "range 1, LPIPS (AlexNet) on [-1, 1] when its weights exist, mean over frames. SSIM as torchmetrics >= 1.5",
                  "computes it and as torchmetrics <= 1.4 did (the valid region only). PSNR, the first SSIM and LPIPS",
                  "are our masked columns above: the same protocol.", "",
                  "| frames | PSNR | SSIM (torchmetrics >= 1.5) | SSIM (torchmetrics <= 1.4) | LPIPS |", "|---|---|---|---|---|",
                  f"| {summary['frames']} | {_fmt(e['psnr'])} | {_fmt(e['ssim'])} | {_fmt(e['ssim_tm14'])} | {_fmt(e['lpips'])} |"]
    atomic_write_text(out / "report.md", "\n".join(lines) + "\n")
