"""The held-out subjects as a plan's capture regime has them (re-rendered with less coverage, pose noise, or
fitted poses) and the fitted poses' error against the truth."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from trioman.bench.ablation_config import AblationPlan
from trioman.runtime.formats import load_subject
from trioman.runtime.frame_selection import FrameSelection
from trioman.toolkit.fit.config import FitConfig, FitRunConfig
from trioman.toolkit.fit.evaluate import compare
from trioman.toolkit.fit.run import fit_video
from trioman.toolkit.synth.linked import link_fitted
from trioman.toolkit.synth.subject import SynthConfig, synthesize_subject


def regime_subject(subject: Path, out: Path, plan: AblationPlan, fit: FitConfig | None = None) -> Path:
    """The held-out subject as the plan's regime captures it: the corpus's own folder, or (coverage < 1, pose
    noise, fitted poses) the same synthetic subject re-rendered with them in OUT/subjects (made once). Fitted poses:
    the re-rendered subject's every frame as a video (OUT/subjects/<name>.mp4) at the plan's ``video_side`` (the
    scene rendered again at that size, OUT/subjects/<name>_video; the same draws at any size), ``trioman fit`` on it
    tracking at the video's size and writing at the subject's, each test frame a shot of its own (``--cuts``: the
    test motions are a few frames of a motion each, from cameras of their own), with a phone's focal prior (OUT/subjects/<name>_fit:
    fit.json, overlays), the fit linked to the truth
    (toolkit/synth/linked.py) with the truth's split: the test frames' poses are fitted too, as a user's are (and
    refitted to their pixels when evaluated).
    ``fit``: the fitter's settings (default: `trioman fit`'s)."""
    if not plan.capture:
        return subject
    target = out / "subjects" / (subject.name + plan.capture)
    if (target / "subject.json").is_file():
        return target
    made = dict(load_subject(subject, check_images=False).meta["generator"])
    made.pop("tool"), made.pop("version")
    cfg = SynthConfig(**{**made, "coverage": plan.coverage, "pose_noise_deg": plan.pose_noise})
    if plan.poses == "true":
        synthesize_subject(cfg, target, progress=False)
        return target
    stem = out / "subjects" / (subject.name + plan.capture)
    truth_dir, video, fit_dir = stem.with_name(stem.name + "_truth"), stem.with_name(stem.name + ".mp4"), stem.with_name(stem.name + "_fit")
    big = dataclasses.replace(cfg, size=plan.video_side) if plan.video_side else cfg
    if not (truth_dir / "subject.json").is_file() or not video.is_file():
        stem.parent.mkdir(parents=True, exist_ok=True)
        if big == cfg:
            synthesize_subject(cfg, truth_dir, overwrite=True, progress=False, video=video, video_frames="all")
        else:
            synthesize_subject(cfg, truth_dir, overwrite=True, progress=False)
            synthesize_subject(big, stem.with_name(stem.name + "_video"), overwrite=True, progress=False, video=video,
                               video_frames="all")
    if not (fit_dir / "subject.json").is_file():
        # the video's frames in the subject's order: the training turn, then the test motions, each a handful of
        # frames spread over a whole motion from a camera of its own (photographs more than a video): every test
        # frame is a shot of its own
        truth = load_subject(truth_dir, check_images=False)
        cuts = tuple(int(k) for k in np.flatnonzero(truth.split == "test") if k > 0)
        run = FitRunConfig(selection=FrameSelection(long_side=max(cfg.width, cfg.height)), track_side=0, test_every=0, cuts=cuts)
        fit_video(video, fit_dir, run if fit is None else dataclasses.replace(run, fit=fit), overwrite=True,
                  progress=False, say=lambda line: print(f"bench ablation: fit {subject.name}: {line}", flush=True))
    link_fitted(load_subject(fit_dir), load_subject(truth_dir), target)
    return target


def fit_error(subject: Path) -> dict | None:
    """A fitted regime subject's pose error against its truth (toolkit/fit/evaluate.compare: MPJPE, PA-MPJPE and
    per group in mm, mask IoU; over all fitted frames, and PA-MPJPE over the test frames), or None for a subject
    of true poses."""
    fitted = subject.with_name(subject.name + "_fit")
    if not (fitted / "subject.json").is_file():
        return None
    linked = load_subject(subject, check_images=False)
    found = compare(linked, load_subject(subject.with_name(subject.name + "_truth"), check_images=False))
    test = np.asarray(found.pop("per_frame_pa_mpjpe_mm"))[linked.split == "test"]
    return {**found, "pa_mpjpe_test": round(float(test.mean()), 1) if len(test) else None}
