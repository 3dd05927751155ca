"""A subject fitted from a synthetic subject's video, linked to its truth.

``trioman fit`` on the video of a synthetic subject (``synthesize_subject(..., video=, video_frames="all")``)
gives a subject in its own world: fitted poses, a fitted camera, the person masks of the segmentation.
``link_fitted`` writes it again with the synthetic subject's split and sequences (the fitted frames named as the
video's frames, so as the synthetic subject's) and the truth it needs: the true poses as ``poses_true`` and, in
subject.json's ``generator.truth``, the synthetic subject's settings and each frame's true root, camera and
intrinsics. ``TruthRenderer`` then renders the truth at the fitted subject's Generator draws: the ceiling of
augmentation on fitted poses.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from trioman.runtime.formats import Subject, save_subject


def link_fitted(fitted: Subject, truth: Subject, out: str | Path, overwrite: bool = False) -> Subject:
    """Write ``fitted`` (frames named as ``truth``'s) into ``out`` with ``truth``'s split and sequences and the link
    to its truth. Every fitted frame must be a frame of ``truth``; a test sequence may lose frames, not all."""
    made = dict(truth.meta.get("generator", {}))
    if made.get("tool") != "trioman synth":
        raise ValueError(f"{truth.root}: not a synthetic subject (subject.json generator.tool is not 'trioman synth')")
    names = {str(n): i for i, n in enumerate(truth.frame_names)}
    unknown = [str(n) for n in fitted.frame_names if str(n) not in names]
    if unknown:
        raise ValueError(f"{fitted.root}: frames {unknown[:3]} are not frames of {truth.root}")
    if fitted.num_joints != truth.num_joints:
        raise ValueError(f"{fitted.root}: {fitted.num_joints} joints against the truth's {truth.num_joints}")
    idx = np.array([names[str(n)] for n in fitted.frame_names])
    lost = sorted(set(truth.sequence[truth.split == "test"].tolist()) - set(truth.sequence[idx].tolist()))
    if lost:
        raise ValueError(f"{fitted.root}: the fit kept no frame of the truth's test sequences {lost}")
    true_poses = truth.poses if truth.poses_true is None else truth.poses_true
    link = {"synth": made, "frames": idx.tolist(), "trans": truth.trans[idx].tolist(),
            "viewmat": truth.viewmat[idx].tolist(), "K": truth.K[idx].tolist()}
    generator = {**fitted.meta.get("generator", {}), "truth": link}
    return save_subject(
        out, body=fitted.body, poses=fitted.poses, trans=fitted.trans, K=fitted.K, viewmat=fitted.viewmat,
        split=truth.split[idx].tolist(), sequence=truth.sequence[idx].tolist(),
        images=(fitted.image(i) for i in range(fitted.num_frames)), masks=(fitted.mask(i) for i in range(fitted.num_frames)),
        width=fitted.width, height=fitted.height, body_model=fitted.body_model, background=fitted.background,
        phenotype=fitted.meta.get("phenotype"), generator=generator, frame_names=[str(n) for n in fitted.frame_names],
        poses_true=true_poses[idx], overwrite=overwrite, inputs=[fitted.root, truth.root])
