"""A fit against the truth of a synthetic subject whose training frames it was fitted on (``trioman synth --video``:
video frame k is the subject's frame k): joint errors in each camera's frame, after root and after Procrustes
alignment, per joint group; the body's turn about the vertical (which Procrustes alignment hides: a pelvis turned
one way and a spine twisted back score well); and the person masks' agreement.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from trioman.runtime.formats import Subject

JOINT_GROUPS = {
    "arms": ("upperarm01.L", "upperarm01.R", "lowerarm01.L", "lowerarm01.R", "wrist.L", "wrist.R"),
    "legs": ("upperleg01.L", "upperleg01.R", "lowerleg01.L", "lowerleg01.R", "foot.L", "foot.R"),
    "head": ("neck01", "head"),
}
ROOT = ("upperleg01.L", "upperleg01.R")  # the hips' centre
# where the body's turn is read: the pelvis (the root) and the chest (the neck's frame)
TURN_JOINTS = {"root": "pelvis", "neck01": "chest"}


def procrustes(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``b`` [M, 3] moved onto ``a`` [M, 3] by the similarity (rotation, scale, translation) that fits best."""
    ma, mb = a.mean(0), b.mean(0)
    A, B = a - ma, b - mb
    U, S, Vt = np.linalg.svd(B.T @ A)
    d = np.sign(np.linalg.det(U @ Vt))
    D = np.diag([1.0, 1.0, d])
    R = U @ D @ Vt  # B @ R ~ A
    scale = (S * np.diag(D)).sum() / max((B ** 2).sum(), 1e-12)
    return scale * B @ R + ma


def _in_camera(subject: Subject, i: int, names: list[str], turn_joints: Iterable[str], true_pose: bool) -> tuple[np.ndarray, list[float]]:
    """Frame ``i``'s joints ``names`` in its camera's frame [M, 3], and the direction each of ``turn_joints`` faces
    (the body's front, -y at rest) about the camera's vertical, degrees: one forward kinematics for both."""
    sk = subject.body.skeleton
    pose = (subject.poses_true if true_pose else subject.poses)[i].astype(np.float64)
    G = sk.forward_kinematics(pose, subject.trans[i].astype(np.float64))
    V = subject.viewmat[i].astype(np.float64)
    joints = G[[sk.index(n) for n in names], :3, 3] @ V[:3, :3].T + V[:3, 3]
    fronts = [V[:3, :3] @ G[sk.index(j), :3, :3] @ np.array([0.0, -1.0, 0.0]) for j in turn_joints]
    return joints, [float(np.degrees(np.arctan2(f[0], -f[2]))) for f in fronts]


def compare(fit: Subject, truth: Subject) -> dict:
    """Per-frame and mean MPJPE (root aligned) and PA-MPJPE in mm, per group; mask IoU of the fit's person
    masks against the true ones. Frames are matched by name."""
    if truth.poses_true is None:
        raise ValueError(f"{truth.root}: records no true poses (not a synthetic subject)")
    names = [n for group in JOINT_GROUPS.values() for n in group]
    by_name = {n: i for i, n in enumerate(truth.frame_names)}
    missing = [n for n in fit.frame_names if n not in by_name]
    if missing:
        raise ValueError(f"{fit.root}: frame {missing[0]} is not a frame of {truth.root}")
    root = [names.index(n) for n in ROOT]
    rows = {"mpjpe": [], "pa_mpjpe": [], **{f"pa_{g}": [] for g in JOINT_GROUPS}, "mask_iou": []}
    turn = {j: [] for j in TURN_JOINTS}
    for k, name in enumerate(fit.frame_names):
        i = by_name[name]
        a, facing_true = _in_camera(truth, i, names, TURN_JOINTS, true_pose=True)
        b, facing_fit = _in_camera(fit, k, names, TURN_JOINTS, true_pose=False)
        a0, b0 = a - a[root].mean(0), b - b[root].mean(0)
        rows["mpjpe"].append(np.linalg.norm(a0 - b0, axis=1).mean())
        err = np.linalg.norm(a - procrustes(a, b), axis=1)
        rows["pa_mpjpe"].append(err.mean())
        start = 0
        for g, joints in JOINT_GROUPS.items():
            rows[f"pa_{g}"].append(err[start:start + len(joints)].mean())
            start += len(joints)
        for j, f, t in zip(TURN_JOINTS, facing_fit, facing_true):
            turn[j].append((f - t + 180.0) % 360.0 - 180.0)
        m_fit, m_true = fit.mask(k) >= 0.5, truth.mask(i) >= 0.5
        if m_fit.shape == m_true.shape:
            rows["mask_iou"].append((m_fit & m_true).sum() / max(1, (m_fit | m_true).sum()))
    out = {k: round(1000 * float(np.mean(v)), 1) if k != "mask_iou" else (round(float(np.mean(v)), 4) if v else None)
           for k, v in rows.items()}
    for j, key in TURN_JOINTS.items():
        err = np.asarray(turn[j])
        err = np.abs(err - np.median(err))  # the camera's own turn about the body, common to every frame, left out
        out[f"{key}_turn_deg"] = round(float(np.median(err)), 1)
        out[f"{key}_turn_p90_deg"] = round(float(np.percentile(err, 90)), 1)
    out["frames"] = len(fit.frame_names)
    out["per_frame_pa_mpjpe_mm"] = [round(1000 * float(v), 1) for v in rows["pa_mpjpe"]]
    return out
