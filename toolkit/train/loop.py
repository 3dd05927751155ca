"""The avatar optimisation loop: losses, schedule and the run's log, in a ``ModelRun`` (toolkit/loops/model_run.py:
resume, the non-finite guard, progress, atomic checkpoints); the run's record and its resume checks are
toolkit/train/resume.py's."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Callable

import numpy as np
import torch

from trioman import __version__
from trioman.runtime.formats import Subject, load_subject
from trioman.runtime.outputs import (
    FolderKind,
    atomic_write_text,
    check_folder_target,
    check_not_input,
    naming_os_errors,
    remove_temp_files,
    process_lock,
)
from trioman.runtime.stages import stage
from trioman.toolkit.avatar.model import Gaussians, GaussianAvatar
from trioman.toolkit.cpu import deterministic_kernels, flush_denormals
from trioman.toolkit.loops.checkpoint import CHECKPOINTS, latest_checkpoint
from trioman.toolkit.loops.guard import StepGuard
from trioman.toolkit.loops.model_run import ModelRun
from trioman.toolkit.metrics import psnr, ssim, ssim_map
from trioman.toolkit.render import rasterize
from trioman.toolkit.train.augmentation import Augmenter
from trioman.toolkit.train.config import TrainConfig, with_subject_defaults
from trioman.toolkit.train.data import join_frames, load_frames
from trioman.toolkit.train.pose_corrections import PoseCorrections
from trioman.toolkit.train.resume import CONFIG_JSON, check_resume, new_record, read_record, write_record

LOG_HEADER = "step,seconds,loss,psnr,lr\n"
TRAIN_LOG = "train_log.csv"  # run/train_log.csv: one line per step
AUGMENT_JSON = "augment.json"  # run/augment.json: the online augmentation's counts and stage times
# An avatar's training run, with the evaluations `trioman eval` writes in it by default (eval_<split>, and the
# benchmarks' eval_<split>_<step>): what a command that starts a fresh run in a fixed folder may remove
_EVAL_FILES = ("*.md", "*.csv", "*.json", "*.png", "*.mp4")
RUN_FOLDER = FolderKind("training run", CONFIG_JSON, files=(CONFIG_JSON, TRAIN_LOG, AUGMENT_JSON),
                        folders=((CHECKPOINTS, ("ckpt_*.pt",)), ("eval_*", _EVAL_FILES)))


def render(g: Gaussians, viewmat: torch.Tensor, K: torch.Tensor, width: int, height: int,
           background: torch.Tensor) -> torch.Tensor:
    """-> [H, W, 3] image of the Gaussians over ``background``."""
    return rasterize(g.means, g.quats, g.scales, g.opacities, g.colors, viewmat, K, width, height, background=background).rgb


def learning_rate(cfg: TrainConfig, step: int) -> float:
    lr = cfg.lr
    for frac in cfg.lr_decay_at:
        if step >= frac * cfg.iterations:
            lr *= 0.1
    return lr


def param_groups(model: GaussianAvatar, cfg: TrainConfig, corrections: PoseCorrections | None = None) -> list[dict]:
    """Adam groups: the per-Gaussian colours at ``cfg.point_color_lr``, the pose corrections at ``cfg.pose_lr``,
    the rest at ``cfg.lr`` (all decay)."""
    point = [p for n, p in model.named_parameters() if n == "point_rgb"]
    rest = [p for n, p in model.named_parameters() if n != "point_rgb"]
    groups = [{"params": rest, "lr_scale": 1.0}]
    if point:
        groups.append({"params": point, "lr_scale": cfg.point_color_lr / cfg.lr})
    if corrections is not None:
        groups.append({"params": list(corrections.parameters()), "lr_scale": cfg.pose_lr / cfg.lr})
    return groups


def photometric(pred: torch.Tensor, gt: torch.Tensor, cfg: TrainConfig, lpips=None,
                pixel_weights: torch.Tensor | None = None) -> torch.Tensor:
    """pred, gt: [H, W, 3] -> L1 0.8 + (1 - SSIM) 0.2 (+ LPIPS 0.2). pixel_weights [H, W] in [0, 1] weight the
    per-pixel L1 and SSIM terms (a pseudo frame supervised only where it is known); None: 1 everywhere."""
    p, g = pred.permute(2, 0, 1)[None], gt.permute(2, 0, 1)[None]
    w = cfg.weights
    if pixel_weights is None:
        loss = w.l1 * (pred - gt).abs().mean() + w.ssim * (1 - ssim(p, g)).mean()
    else:
        pw = pixel_weights[..., None]
        loss = w.l1 * (pw * (pred - gt).abs()).mean() + w.ssim * (pw.permute(2, 0, 1)[None] * (1 - ssim_map(p, g))).mean()
    if lpips is not None:
        loss = loss + w.lpips * lpips(p, g).mean()
    return loss


def regularisers(model: GaussianAvatar, out, cfg: TrainConfig) -> torch.Tensor:
    w = cfg.weights
    reg = w.offset * out.offset.square().sum(-1).mean() + w.scale * out.log_scale.square().mean()
    reg = reg + w.lap_offset * model.laplacian(out.offset).square().sum(-1).mean()
    reg = reg + w.lap_scale * model.laplacian(out.log_scale).square().mean()
    if model.cfg.pose_dependent:
        reg = reg + w.delta_offset * out.delta_offset.square().sum(-1).mean()
        reg = reg + w.delta_rgb * out.delta_rgb.square().sum(-1).mean()
    return reg


def _prepare_run(run: Path, subject: Subject, cfg: TrainConfig, resume: bool,
                 extend_iterations: int | None) -> tuple[TrainConfig, dict]:
    """-> the config to train with and the run's record (config.json), checked against the run when resuming
    (toolkit/train/resume.py); writes nothing but removes an interrupted run's temporary files."""
    if not (run / CONFIG_JSON).exists():
        if extend_iterations is not None:
            raise FileNotFoundError(f"extend_iterations: no run in {run} to extend")
        return cfg, new_record(subject, cfg)
    if not resume:
        raise FileExistsError(f"{run}: a run is already there (pass `resume` to continue it, or choose another `run`)")
    remove_temp_files(run)
    ckpt = latest_checkpoint(run)
    step = 0 if ckpt is None else int(ckpt.stem.split("_")[1])
    return check_resume(run, read_record(run), subject, cfg, step, extend_iterations)


def _extra_subject(cfg: TrainConfig, subject: Subject) -> Subject:
    """The subject folder of ``cfg.extra_frames``, checked against the training subject."""
    extra = load_subject(cfg.extra_frames)
    if (extra.width, extra.height) != (subject.width, subject.height):
        raise ValueError(f"extra_frames: {cfg.extra_frames} has {extra.width}x{extra.height} (W x H) images, but the "
                         f"subject {subject.root} has {subject.width}x{subject.height}")
    if extra.body.skeleton.joint_names != subject.body.skeleton.joint_names:
        raise ValueError(f"extra_frames: {cfg.extra_frames} has a body of {extra.num_joints} joints that differs from "
                         f"the subject's ({subject.num_joints} joints); augment frames of this subject")
    return extra


def _trim_log(log: Path, step: int) -> None:
    """Keep the log lines up to ``step`` (a resumed run rewrites what came after its checkpoint)."""
    if not log.exists():
        atomic_write_text(log, LOG_HEADER)
        return
    lines = log.read_text().splitlines(keepends=True)
    kept = [lines[0]] + [ln for ln in lines[1:] if ln.strip() and int(ln.split(",")[0]) <= step]
    atomic_write_text(log, "".join(kept))


@flush_denormals()
@deterministic_kernels()
def _run_is_there(run: Path) -> FileExistsError:
    return FileExistsError(f"{run}: a run is already there (pass `resume` to continue it, or choose another `run`)")


def train(subject_path: str | Path, run: str | Path, cfg: TrainConfig, resume: bool = False, progress: bool = True,
          stop_after: int | None = None, lpips=None, on_checkpoint: Callable[[int, Path], None] | None = None,
          extend_iterations: int | None = None) -> Path:
    """Train an avatar on the subject's training frames (plus ``cfg.extra_frames``) into the folder ``run``.

    ``resume`` continues the run in ``run`` when the subject, config and code are the run's (else ValueError
    naming what differs); ``extend_iterations`` continues it to that many iterations in total (recorded in
    config.json). Same seed and thread count, same weights (deterministic kernels). ``stop_after`` ends the
    loop after that many steps of this call (to test interruption); ``on_checkpoint(step, path)`` is called
    after each checkpoint (benchmarks evaluate there). config.json is written once every input has loaded.
    """
    run, subject_path = Path(run), Path(subject_path)
    if not resume and (run / CONFIG_JSON).exists():
        raise _run_is_there(run)
    if extend_iterations is not None and not resume:
        raise ValueError("extend_iterations: needs `resume` (it continues a run)")
    inputs = [subject_path, cfg.extra_frames]
    try:  # a new run takes an absent or empty folder, never one inside or around what it reads
        if (run / CONFIG_JSON).exists():
            check_not_input(run, inputs)
        else:
            check_folder_target(run, False, inputs=inputs)
    except ValueError as err:
        raise ValueError(f"run: {err}") from None
    # one writer per run: a second `train` into the same folder is refused while this one runs (the lock lies
    # beside the run, whose folder it would otherwise fill before the checks above hold)
    with process_lock(run.parent / f".{run.name}.train.lock", f"run: another `train` into {run}"):
        if not resume and (run / CONFIG_JSON).exists():  # one that ran while this one was checking its inputs
            raise _run_is_there(run)
        subject = load_subject(subject_path)
        cfg = with_subject_defaults(cfg, subject.meta.get("generator", {}).get("tool"))
        cfg, record = _prepare_run(run, subject, cfg, resume, extend_iterations)
        frames = load_frames(subject, "train" if cfg.frames == "train" else None, cfg.image_scale, cfg.frame_stride)
        own = len(frames)  # the subject's own frames come first in the set (pose corrections apply to them)
        if cfg.extra_frames is not None:  # uniform sampling over the union of both frame sets
            extra = _extra_subject(cfg, subject)
            frames = join_frames(frames, load_frames(extra, None, cfg.image_scale), cfg.extra_weight)
        model = GaussianAvatar(subject.body, cfg.avatar)
        corrections = PoseCorrections(subject.sequence, subject.num_joints, cfg.pose_knot_every) if cfg.refine_poses else None
        augmenter = None if cfg.augment is None else Augmenter(cfg.augment, subject, frames, cfg.iterations, cfg.seed)
        optimizer = torch.optim.Adam(param_groups(model, cfg, corrections), lr=cfg.lr, eps=1e-15)
        rng = np.random.default_rng(cfg.seed)
        torch_gen = torch.Generator().manual_seed(cfg.seed)
        # The run's config was checked against its record (_prepare_run), not against the checkpoint's; a run not
        # asked to resume loads no checkpoint; the bar opens once the run is there.
        loop = ModelRun("train", None, model, optimizer, cfg, run, progress, steps=cfg.iterations, resume=resume, unit="it",
                        open_bar=False)
        seconds = 0.0
        if loop.resumed:
            seconds = float(loop.resumed["seconds"])
            rng.bit_generator.state = json.loads(loop.resumed["numpy_rng"])
            torch_gen.set_state(loop.resumed["torch_rng"])
            if augmenter is not None:
                augmenter.load_state_dict(loop.resumed["augment"], model)
            if corrections is not None:
                corrections.load_state_dict(loop.resumed["pose_corrections"])
        write_record(run, record)  # every input has loaded: from here on the run is there (and resumable)
        log = run / TRAIN_LOG
        _trim_log(log, loop.step)

        def checkpoint() -> None:
            loop.check_weights()
            loop.save({
                "step": loop.step, "seconds": seconds, "skipped": loop.guard.skipped, "model": model.state_dict(),
                "optimizer": optimizer.state_dict(),
                "numpy_rng": json.dumps(rng.bit_generator.state), "torch_rng": torch_gen.get_state(),
                "config": json.dumps(cfg.to_dict()), "trioman_version": __version__,
                **({} if augmenter is None else {"augment": augmenter.state_dict()}),
                **({} if corrections is None else {"pose_corrections": corrections.state_dict()}),
            })
            if augmenter is not None:
                atomic_write_text(run / AUGMENT_JSON, json.dumps(augmenter.summary(loop.step), indent=2) + "\n")
            if on_checkpoint is not None:
                on_checkpoint(loop.step, loop.saved)

        loop.open_bar()
        done_here = 0
        run_psnr = None
        with naming_os_errors(log), log.open("a") as log_file:
            while loop.running and (stop_after is None or done_here < stop_after):
                t0 = time.perf_counter()
                step = loop.step
                for group in optimizer.param_groups:
                    group["lr"] = learning_rate(cfg, step) * group["lr_scale"]
                if augmenter is not None and augmenter.due(step):
                    augmenter.rebuild(model)
                sample = augmenter.draw() if augmenter is not None and augmenter.use_pseudo(step) else None
                if sample is None:  # a real frame (also when the Examiner dropped every pool entry)
                    k = int(rng.integers(len(frames)))
                    sample = frames.sample(k)
                    if corrections is not None and k < own and step >= cfg.pose_start * cfg.iterations:
                        sample["frame"] = int(frames.indices[k])
                loss, p = train_step(model, optimizer, sample, cfg, torch_gen, lpips, loop.guard, step, corrections)
                done_here += 1
                seconds += time.perf_counter() - t0
                if np.isfinite(p):
                    run_psnr = p if run_psnr is None else 0.9 * run_psnr + 0.1 * p
                log_file.write(f"{step + 1},{seconds:.3f},{loss:.6f},{p:.4f},{learning_rate(cfg, step):.3g}\n")
                # every step's loss, a skipped step's too, as in the log (the bar shows it; loop.losses is not read)
                if loop.advance(loss, psnr=f"{run_psnr or 0:.2f}"):
                    log_file.flush()
                    checkpoint()
        loop.finish()
        return run


def train_step(model: GaussianAvatar, optimizer: torch.optim.Optimizer, sample: dict, cfg: TrainConfig,
               torch_gen: torch.Generator, lpips, guard: StepGuard, step: int,
               corrections: PoseCorrections | None = None) -> tuple[float, float]:
    """One optimisation step on one frame (``FrameSet.sample`` or a pseudo-GT pool frame). A sample naming its
    subject ``frame`` is posed with that frame's learnt ``corrections`` (and their penalty is added).

    A non-finite loss or gradient skips the update and counts it in ``guard`` (which stops the run after
    ``cfg.max_skipped`` in a row). -> (loss, PSNR of the render) as floats.
    """
    bg = torch.rand(3, generator=torch_gen) if cfg.random_background else torch.ones(3)
    gt = sample["images"] + (1 - sample["masks"])[..., None] * bg  # premultiplied GT over the same colour
    pose, trans = sample["poses"], sample["trans"]
    if corrections is not None and "frame" in sample:
        pose, trans = corrections.apply(sample["frame"], pose, trans)
    out = model(pose, trans)
    sets = [out.refined] + ([out.plain] if cfg.supervise_plain else [])
    height, width = gt.shape[:2]
    loss = torch.zeros(())
    pred = None
    for g in sets:
        img = render(g, sample["viewmat"], sample["K"], width, height, bg)
        pred = img if pred is None else pred
        with stage("loss"):
            loss = loss + sample["weight"] * photometric(img, gt, cfg, lpips, sample.get("pixel_weights"))
    with stage("loss"):
        loss = loss + regularisers(model, out, cfg)
        if corrections is not None and "frame" in sample:
            loss = loss + cfg.weights.pose_correction * corrections.penalty(sample["frame"])
    hint = f"(learning rate {learning_rate(cfg, step):.3g}; the last checkpoint is intact)"
    optimizer.zero_grad(set_to_none=True)
    if guard.finite_ok(loss, step, "loss", hint):
        with stage("backward"):
            loss.backward()
        params = [*model.parameters(), *([] if corrections is None else corrections.parameters())]
        if guard.grads_ok(params, step, hint):
            with stage("optimizer"):
                optimizer.step()
    with torch.no_grad():
        p = float(psnr(pred.permute(2, 0, 1)[None].clamp(0, 1), gt.permute(2, 0, 1)[None])[0])
    return float(loss.detach()), p
