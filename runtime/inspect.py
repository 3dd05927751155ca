"""A subject folder's summary lines (``trioman inspect``: trioman/commands/inspect.py).

Standard-library imports only at module level (the command builds its parser from ``InspectOptions``); numpy and
the runtime are imported inside ``summarize``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from trioman.runtime.options import check_options, option


@dataclass(frozen=True)
class InspectOptions:
    """What ``trioman inspect`` checks (``load_subject``'s ``check_images`` defaults to it)."""

    check_images: bool = option(True, flag="--images",
                                help="check that every frame's image and mask exists with the right size")

    def __post_init__(self) -> None:
        check_options(self)


def _noise_entries(value: Any, prefix: str = "") -> list[tuple[str, Any]]:
    """Entries of the free-form generator record whose key mentions noise (nested keys joined by '.')."""
    found: list[tuple[str, Any]] = []
    if isinstance(value, dict):
        for k, v in value.items():
            key = f"{prefix}{k}"
            if "noise" in str(k).lower() and not isinstance(v, dict):
                found.append((key, v))
            else:
                found.extend(_noise_entries(v, key + "."))
    return found


def summarize(subject) -> list[str]:
    """The summary lines printed by ``trioman inspect``."""
    import numpy as np

    from trioman.runtime.rotations import axis_angle_to_matrix

    s = subject
    body = s.body
    lines = [
        f"subject     {s.root}",
        f"format      {s.meta['format']} v{s.meta['version']}",
        f"body        {s.body_model}: {body.skeleton.num_joints} joints, {body.num_vertices} vertices, "
        f"{len(body.faces)} faces{', with uvs' if body.uvs is not None else ''}",
        f"images      {s.width} x {s.height} (W x H), background {[round(c, 4) for c in s.meta['background']]}",
    ]
    counts = {sp: int((s.split == sp).sum()) for sp in ("train", "test")}
    lines.append(f"frames      {s.num_frames} (train {counts['train']}, test {counts['test']})")
    width = max(len(q) for q in s.sequences)
    lines.append(f"sequences   {len(s.sequences)}")
    lines.append(f"  {'name'.ljust(width)}  {'train':>6}  {'test':>6}")
    for q in s.sequences:
        in_q = s.sequence == q
        tr, te = int((in_q & (s.split == "train")).sum()), int((in_q & (s.split == "test")).sum())
        lines.append(f"  {q.ljust(width)}  {tr:>6}  {te:>6}")
    root = body.skeleton.joints[0][None] + s.trans.astype(np.float64)  # root joint in world (G_0 translation)
    dist = np.linalg.norm(s.camera_centers() - root, axis=1)
    lines.append(f"camera      distance to root joint {dist.min():.3f} .. {dist.max():.3f} m (median {np.median(dist):.3f})")
    fx = s.K[:, 0, 0]
    lines.append(f"            focal fx {fx.min():.1f} .. {fx.max():.1f} px")
    phenotype = s.meta.get("phenotype", {})
    if phenotype:
        shown = ", ".join(f"{k}={v:g}" for k, v in list(phenotype.items())[:8])
        more = f", ... ({len(phenotype)} in all)" if len(phenotype) > 8 else ""
        lines.append(f"phenotype   {shown}{more}")
    gen = s.meta.get("generator", {})
    tool = ", ".join(f"{k} {gen[k]}" for k in ("tool", "seed") if k in gen)
    if tool:
        lines.append(f"generator   {tool}")
    noise = _noise_entries(gen)
    if noise:
        lines.append("pose noise  " + ", ".join(f"{k} = {v}" for k, v in noise))
    if s.poses_true is not None:
        R_fit = axis_angle_to_matrix(s.poses.astype(np.float64))
        R_true = axis_angle_to_matrix(s.poses_true.astype(np.float64))
        cos = (np.einsum("...ij,...ij->...", R_fit, R_true) - 1.0) / 2.0  # trace(R_fit^T R_true)
        angle = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
        lines.append(
            f"poses_true  recorded; stored vs true joint rotation: mean {angle.mean():.2f} deg, max {angle.max():.2f} deg"
        )
    else:
        lines.append("poses_true  not recorded")
    return lines
