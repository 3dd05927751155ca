"""``trioman fit``: a person's video (or a folder of frames) -> a subject folder with the Anny body fitted to it.

Stages, each one printed line when it ends: read and track (the person model on every selected frame,
``trioman.runtime.person``; frames without one clear, whole person are dropped with the reason), fit
(``toolkit/fit/fitter.py``), write (the subject: frames premultiplied by the person masks, as ``import`` stores
a capture; the video is read a second time, so only the masks stay in memory), report (``fit.json``,
``fit.md``, the fitted body over the frames as ``fit_overlay.png`` and ``fit_overlay.mp4``).
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from trioman import __version__
from trioman.runtime.formats import Subject, save_subject
from trioman.runtime.formats.subject import FIT_REPORT_FILES
from trioman.runtime.image_io import VideoWriter, write_png
from trioman.runtime.outputs import atomic_write_text, check_not_input
from trioman.runtime.mesh_raster import rasterize_mesh
from trioman.runtime.person import PersonTracker
from trioman.runtime.preview import contact_sheet
from trioman.runtime.stages import StageLog
from trioman.runtime.frame_selection import FrameSelection
from trioman.runtime.video_input import VideoInfo, open_frames, scaled_size
from trioman.toolkit.fit.config import FitConfig, FitRunConfig
from trioman.toolkit.fit.fitter import DIST_MAP_SIDE, FitResult, Observations, fit_sequence
from trioman.toolkit.train.config import FITTED_BY

FIT_JSON, FIT_MD, OVERLAY_PNG, OVERLAY_MP4 = FIT_REPORT_FILES
SEQUENCE = "video"


@dataclass
class _Tracked:
    """Every selected frame's verdict, and the kept frames' observations."""

    names: list[str] = field(default_factory=list)  # all selected frames
    indices: list[int] = field(default_factory=list)
    statuses: list[str] = field(default_factory=list)
    reasons: list[str] = field(default_factory=list)
    kept: list[int] = field(default_factory=list)  # positions in the lists above
    keypoints: list[np.ndarray] = field(default_factory=list)
    confidence: list[np.ndarray] = field(default_factory=list)
    world: list[np.ndarray] = field(default_factory=list)
    masks: list[np.ndarray] = field(default_factory=list)  # uint8 [H, W], kept frames
    size: tuple[int, int] | None = None  # (W, H)


def _track(source: Path, selection: FrameSelection, cfg: FitRunConfig, progress: bool) -> tuple[VideoInfo, _Tracked]:
    info, frames = open_frames(source, selection)
    tracker = PersonTracker(cfg.tracker)
    out = _Tracked()
    total = info.frames if info.frames is not None else None
    for index, name, frame in tqdm(frames, total=total, desc="fit: tracking", unit="frame", disable=None if progress else True):
        p = tracker(frame)
        out.size = (frame.shape[1], frame.shape[0])
        out.names.append(name)
        out.indices.append(index)
        out.statuses.append(p.status)
        out.reasons.append(p.reason)
        if p.ok:
            out.kept.append(len(out.names) - 1)
            out.keypoints.append(p.keypoints)
            out.confidence.append(p.confidence)
            out.world.append(p.world)
            out.masks.append(np.rint(np.clip(p.mask, 0, 1) * 255).astype(np.uint8))
    if not out.names:
        raise ValueError(f"{source}: the selection kept no frame")
    if len(out.kept) < 2:
        why = "; ".join(sorted({f"{s}: {r}" for s, r in zip(out.statuses, out.reasons) if s != "ok"}))[:400]
        raise ValueError(f"{source}: {len(out.kept)} of {len(out.names)} frames show one whole person (need 2); {why}")
    return info, out


def _observations(t: _Tracked, cuts: tuple[int, ...] = ()) -> Observations:
    W, H = t.size
    scale = min(1.0, DIST_MAP_SIDE / max(W, H))
    small = (max(1, round(W * scale)), max(1, round(H * scale)))
    masks = np.stack([cv2.resize(m, small, interpolation=cv2.INTER_AREA) for m in t.masks]).astype(np.float32) / 255.0
    index = np.array([t.indices[k] for k in t.kept])
    return Observations(keypoints=np.stack(t.keypoints), confidence=np.stack(t.confidence), world=np.stack(t.world),
                        masks=masks, frame_index=index, width=W, height=H,
                        clip=np.searchsorted(np.sort(cuts), index, side="right") if cuts else None)


def _focal(cfg: FitRunConfig, size: tuple[int, int], track_size: tuple[int, int]) -> float | None:
    """The focal given (``--focal`` at the output ``size``, or ``--fov``) in pixels at the tracking size, or None."""
    if cfg.fov_deg is not None:
        return 0.5 * max(track_size) / math.tan(math.radians(cfg.fov_deg) / 2)
    return None if cfg.focal is None else cfg.focal * max(track_size) / max(size)


def _body_masks(result: FitResult, mesh, size: tuple[int, int]) -> list[np.ndarray]:
    """The fitted body's silhouette in every kept frame. -> [N] bool [H, W]"""
    W, H = size
    return [rasterize_mesh(mesh.pose(result.poses[k], result.trans[k]), mesh.faces, result.viewmat, result.K, W, H).face_id >= 0
            for k in range(len(result.poses))]


def _overlay(frame: np.ndarray, body: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """The frame with the fitted body tinted blue and the person mask's outline green. -> float32 [H, W, 3]"""
    img = frame.astype(np.float32) / 255.0
    img[body] = 0.55 * img[body] + 0.45 * np.array([0.2, 0.45, 1.0])
    edge = cv2.morphologyEx((mask >= 128).astype(np.uint8), cv2.MORPH_GRADIENT, np.ones((3, 3), np.uint8)).astype(bool)
    img[edge] = (0.1, 0.9, 0.2)
    return img


def fit_video(source: str | Path, out: str | Path, cfg: FitRunConfig | None = None, overwrite: bool = False,
              progress: bool = True, say=print) -> Subject:
    """Fit ``source`` (a video file or a folder of frames) into the subject folder ``out`` (its report files
    inside); see the module docstring."""
    cfg = cfg if cfg is not None else FitRunConfig()
    source, out = Path(source), Path(out)
    check_not_input(out, [source])
    log = StageLog(say=say)
    started = time.perf_counter()
    track = cfg.tracking
    with log.stage("read and track"):
        info, tracked = _track(source, track, cfg, progress)
    obs = _observations(tracked, cfg.cuts)
    size = scaled_size(info.width, info.height, cfg.selection.long_side)  # the subject's (W, H)
    focal = _focal(cfg, size, tracked.size)
    fit_cfg = cfg.fit if focal is None else dataclasses.replace(cfg.fit, focal=focal, refine_focal=False)
    from trioman.toolkit.body.registry import create_body_model  # torch and Anny, after the cheap checks

    import torch

    base = create_body_model("anny", dtype=torch.float32).to_skinned_mesh()
    with log.stage("fit"):
        bar = tqdm(total=fit_cfg.key_iterations + fit_cfg.all_iterations, desc="fit: optimising", disable=None if progress else True)
        result = fit_sequence(obs, base, fit_cfg, progress=lambda stage, it, n: bar.update(1))
        bar.close()
    mesh = create_body_model("anny", phenotype=result.phenotype, dtype=torch.float64).to_skinned_mesh()
    W, H = tracked.size
    kept = tracked.kept
    split = ["test" if cfg.test_every and (k % cfg.test_every) == cfg.test_every // 2 else "train" for k in range(len(kept))]
    with log.stage("body masks"):
        bodies = _body_masks(result, mesh, tracked.size)
    iou = np.array([((b & (m >= 128)).sum() / max(1, (b | (m >= 128)).sum())) for b, m in zip(bodies, tracked.masks)])

    def kept_frames(selection: FrameSelection):
        """Re-read the source; the kept frames in order (uint8)."""
        wanted = {tracked.indices[k] for k in kept}
        _, frames = open_frames(source, selection)
        for index, _name, frame in frames:
            if index in wanted:
                yield frame

    # the camera and the masks at the subject's size: pixel coordinates scale with the image ([0, W] x [0, H])
    K = np.diag([size[0] / W, size[1] / H, 1.0]) @ result.K
    with log.stage("write subject"):
        masks = tracked.masks if size == (W, H) else [cv2.resize(m, size, interpolation=cv2.INTER_AREA) for m in tracked.masks]
        generator = {"tool": FITTED_BY, "version": __version__, "source": source.name,
                     "selection": dataclasses.asdict(cfg.selection), "track_size": [W, H], "focal": float(K[0, 0]),
                     "fit": {k: v for k, v in dataclasses.asdict(fit_cfg).items() if k != "phenotype"}}
        subject = save_subject(
            out, body=mesh, poses=result.poses.astype(np.float32), trans=result.trans.astype(np.float32),
            K=np.repeat(K[None], len(kept), 0).astype(np.float32),
            viewmat=np.repeat(result.viewmat[None], len(kept), 0).astype(np.float32),
            split=split, sequence=[SEQUENCE if obs.clip is None else f"{SEQUENCE}_shot{c}" for c in obs.clips],
            images=(f.astype(np.float32) / 255.0 * (m[..., None] / 255.0) for f, m in zip(kept_frames(cfg.selection), masks)),
            masks=(m.astype(np.float32) / 255.0 for m in masks),
            width=size[0], height=size[1], body_model="anny", background=(0.0, 0.0, 0.0), phenotype=result.phenotype,
            generator=generator, frame_names=[tracked.names[k] for k in kept], overwrite=overwrite,
        )
    with log.stage("report"):
        picks = np.unique(np.linspace(0, len(kept) - 1, min(12, len(kept))).round().astype(int))
        shown = {}
        with VideoWriter(out / OVERLAY_MP4, info.fps or 30.0) as video:
            for k, frame in enumerate(kept_frames(track)):
                img = _overlay(frame, bodies[k], tracked.masks[k])
                video.write(img)
                if k in picks:
                    shown[k] = img
        write_png(out / OVERLAY_PNG, contact_sheet([shown[k] for k in picks],
                                                   [f"{tracked.names[kept[k]]} {result.reprojection_px[k]:.1f}px IoU {iou[k]:.2f}"
                                                    for k in picks], cols=6))
        report = _report(source, info, cfg, fit_cfg, tracked, result, iou, split, size, time.perf_counter() - started)
        atomic_write_text(out / FIT_JSON, json.dumps(report, indent=1) + "\n")
        atomic_write_text(out / FIT_MD, _markdown(report))
    return subject


def _report(source: Path, info: VideoInfo, cfg: FitRunConfig, fit_cfg: FitConfig, t: _Tracked, result: FitResult,
            iou: np.ndarray, split: list[str], size: tuple[int, int], seconds: float) -> dict:
    kept_at = {pos: k for k, pos in enumerate(t.kept)}
    frames = []
    for pos, name in enumerate(t.names):
        row = {"name": name, "index": t.indices[pos], "status": t.statuses[pos]}
        if pos in kept_at:
            k = kept_at[pos]
            row.update(split=split[k], reprojection_px=round(float(result.reprojection_px[k]), 3), mask_iou=round(float(iou[k]), 4),
                       mirrored=bool(result.mirrored[k]))
        else:
            row["reason"] = t.reasons[pos]
        frames.append(row)
    dropped: dict[str, int] = {}
    for s in t.statuses:
        if s != "ok":
            dropped[s] = dropped.get(s, 0) + 1
    return {
        "format": "trioman-fit", "version": 1, "trioman": __version__, "source": str(source),
        "video": {"kind": info.kind, "fps": info.fps, "frames": info.frames, "width": info.width, "height": info.height,
                  "rotation": info.rotation},
        "selection": dataclasses.asdict(cfg.selection), "cuts": list(cfg.cuts), "size": list(size), "track_size": list(t.size),
        "camera": {"focal_px": round(float(result.K[0, 0]) * size[0] / t.size[0], 3), "focal_given": fit_cfg.focal is not None,
                   "viewmat": np.round(result.viewmat, 6).tolist()},
        "phenotype": result.phenotype,
        "summary": {"frames_read": len(t.names), "frames_kept": len(t.kept), "dropped": dropped,
                    "mirrored": int(result.mirrored.sum()),
                    "reprojection_px_mean": round(float(result.reprojection_px.mean()), 3),
                    "reprojection_px_max": round(float(result.reprojection_px.max()), 3),
                    "mask_iou_mean": round(float(iou.mean()), 4), "seconds": round(seconds, 1)},
        "losses": {k: round(v, 6) for k, v in result.losses.items()},
        "frames": frames,
    }


def _markdown(r: dict) -> str:
    s = r["summary"]
    dropped = ", ".join(f"{k} {v}" for k, v in sorted(s["dropped"].items())) or "none"
    tracked = "" if r["track_size"] == r["size"] else (f" (tracked and fitted at {r['track_size'][0]}x{r['track_size'][1]}: "
                                                        "the reprojection errors and the overlays are at that size)")
    lines = [
        f"# trioman fit: {Path(r['source']).name}", "",
        f"{s['frames_kept']} of {s['frames_read']} selected frames kept (dropped: {dropped}); "
        f"{r['size'][0]}x{r['size'][1]} px{tracked}, focal {r['camera']['focal_px']} px "
        f"({'given' if r['camera']['focal_given'] else 'fitted from the phone prior'}); {s['seconds']} s. "
        f"{s['mirrored']} kept frames were read mirrored by the pose model (front taken for back) and had their "
        "left and right exchanged.", "",
        "| quantity | mean | worst |", "|---|---|---|",
        f"| landmark reprojection error (px, confidence-weighted) | {s['reprojection_px_mean']} | {s['reprojection_px_max']} |",
        f"| fitted body vs person mask, IoU (clothes and hair make it < 1) | {s['mask_iou_mean']} | "
        f"{min((f['mask_iou'] for f in r['frames'] if 'mask_iou' in f), default=float('nan')):.4f} |", "",
        "Shape: " + ", ".join(f"{k} {v}" for k, v in r["phenotype"].items()) + ".", "",
    ]
    gone = [f for f in r["frames"] if f["status"] != "ok"]
    if gone:
        lines += ["| dropped frame | why |", "|---|---|"] + [f"| {f['name']} | {f['status']}: {f['reason']} |" for f in gone[:50]]
        if len(gone) > 50:
            lines.append(f"| ... | {len(gone) - 50} more in fit.json |")
        lines.append("")
    lines.append(f"The fitted body over the frames: {OVERLAY_PNG}, {OVERLAY_MP4}.")
    return "\n".join(lines) + "\n"
