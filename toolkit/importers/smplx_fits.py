"""A user's own video fitted with SMPL-X by a fitter (SMPLer-X's layout) -> a subject folder.

SMPLer-X writes per frame and person ``smplx/{frame:05}_{person}.npz`` (``global_orient`` [1, 3],
``body_pose`` [21, 3], ``left_hand_pose`` / ``right_hand_pose`` [15, 3], ``jaw_pose`` [1, 3], ``betas``
[1, 10], ``expression`` [1, 10], ``transl`` [1, 3]; eye poses optional) and ``meta/{frame:05}_{person}.json``
(``focal`` [2], ``princpt`` [2], pixels of the full frame). The parameters are in the camera frame of a
camera at the origin (R = I, t = 0). Person 0 is imported; the body's shape is the mean of the per-frame
betas, each frame's translation corrected so its pelvis stays where its own betas put it. Frames come from FRAMES_DIR (``N.png`` / ``.jpg``, N the frame number) and masks (255 = person)
from ``--masks`` (default: a ``masks/`` folder next to FRAMES_DIR).
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Callable

import numpy as np

from trioman.runtime.formats import FormatError, Subject
from trioman.toolkit.body.smplx_model import SMPLXBody
from trioman.toolkit.importers.common import (
    FrameRecord, array, check_target, focal_array, images_by_index, pelvis_per_beta, read_gray, read_json, read_npz,
    smplx_params, write_subject,
)
from trioman.toolkit.importers.options import SmplxFitsOptions

SMPLERX_KEYS = {"root": "global_orient", "body": "body_pose", "jaw": "jaw_pose", "leye": "leye_pose",
                "reye": "reye_pose", "lhand": "left_hand_pose", "rhand": "right_hand_pose", "transl": "transl"}
_STEM = re.compile(r"(\d+)_(\d+)")


def _fit_files(fits_dir: Path) -> tuple[dict[int, Path], int]:
    """Person 0's (lowest person id's) .npz per frame number, and how many frames hold several people."""
    folder = fits_dir / "smplx" if (fits_dir / "smplx").is_dir() else fits_dir
    found: dict[int, tuple[int, Path]] = {}
    people: dict[int, int] = {}
    for p in sorted(folder.glob("*.npz")):
        m = _STEM.fullmatch(p.stem)
        if m is None:
            raise FormatError(f"{p}: expected a name FRAME_PERSON.npz (e.g. 00012_0.npz), as SMPLer-X writes")
        frame, person = int(m[1]), int(m[2])
        people[frame] = people.get(frame, 0) + 1
        if frame not in found or person < found[frame][0]:
            found[frame] = (person, p)
    if not found:
        raise FormatError(f"{folder}: no SMPL-X fits (*.npz)")
    return {f: p for f, (_, p) in found.items()}, sum(n > 1 for n in people.values())


def _meta_file(fits_dir: Path, fit: Path) -> Path:
    for candidate in (fits_dir / "meta" / f"{fit.stem}.json", fit.with_suffix(".json")):
        if candidate.is_file():
            return candidate
    return fits_dir / "meta" / f"{fit.stem}.json"


def import_smplx_fits(frames_dir: str | Path, fits_dir: str | Path, out: str | Path, model_dir: str | Path,
                      masks_dir: str | Path | None = None, gender: str = SmplxFitsOptions.gender,
                      flat_hand_mean: bool = SmplxFitsOptions.flat_hand_mean, test_every: int = SmplxFitsOptions.test_every,
                      overwrite: bool = False, say: Callable[[str], None] = print,
                      up: str = SmplxFitsOptions.up) -> Subject:
    """Write the subject; every ``test_every``-th frame is a test frame (0: none). Nothing is written on error."""
    frames_dir, fits_dir = Path(frames_dir), Path(fits_dir)
    masks_dir = Path(masks_dir) if masks_dir is not None else frames_dir.parent / "masks"
    if test_every < 0:
        raise ValueError(f"test_every: must be >= 0, got {test_every}")
    inputs = (frames_dir, fits_dir, masks_dir)
    check_target(out, overwrite, list(inputs))
    images = images_by_index(frames_dir, "frames")
    masks = images_by_index(masks_dir, "masks (give `masks_dir`: one PNG per frame, 255 = person)")
    fits, crowded = _fit_files(fits_dir)
    if crowded:
        say(f"import: {crowded} of {len(fits)} frames hold several people; person 0 of each frame is imported, but "
            f"SMPLer-X numbers the people of each frame anew (the detector's order; without --multi_person it keeps "
            f"only the largest detection) and never tracks them, so person 0 may change from frame to frame")
    for what, table, folder in (("SMPL-X fit", fits, fits_dir), ("mask", masks, masks_dir)):
        missing = sorted(set(images) - set(table))
        if missing:
            raise FormatError(f"{folder}: no {what} for frame {missing[0]} ({images[missing[0]].name}); "
                              f"{len(images)} frames, {len(table)} {what}s")
    extra = sorted(set(fits) - set(images))
    if extra:
        raise FormatError(f"{fits[extra[0]]}: a fit for frame {extra[0]}, which has no image in {frames_dir}")
    records, betas = [], []
    for n, idx in enumerate(sorted(images)):
        fit = fits[idx]
        arrays = read_npz(fit)
        params = smplx_params(fit, arrays, SMPLERX_KEYS, defaults=("leye", "reye"))
        if "betas" not in arrays:
            raise FormatError(f"{fit}: betas: missing array")
        betas.append(array(fit, "betas", arrays["betas"], (np.size(arrays["betas"]),)))
        if betas[-1].shape != betas[0].shape:
            raise FormatError(f"{fit}: betas: {betas[-1].size} values, but {fits[min(images)]} has {betas[0].size}")
        meta_path = _meta_file(fits_dir, fit)
        meta = read_json(meta_path)
        if not isinstance(meta, dict):
            raise FormatError(f"{meta_path}: expected an object with focal and princpt")
        for key in ("focal", "princpt"):
            if key not in meta:
                raise FormatError(f"{meta_path}: {key}: missing field")
        mask_path = masks[idx]
        records.append(FrameRecord(
            name=images[idx].stem, split="test" if test_every and n % test_every == test_every - 1 else "train",
            sequence=frames_dir.name or "video", image=images[idx],
            mask=lambda p=mask_path: (read_gray(p) > 0.5).astype(np.float32), params=params, R=np.eye(3),
            t=np.zeros(3), focal=focal_array(meta_path, "focal", meta["focal"]),
            princpt=array(meta_path, "princpt", meta["princpt"], (2,)), in_camera=True, mask_file=mask_path))
    mean_betas = np.mean(betas, axis=0)
    body = SMPLXBody(model_dir, gender=gender, num_betas=len(mean_betas), flat_hand_mean=flat_hand_mean, betas=mean_betas)
    # One shape for all frames: keep each frame's pelvis where its own betas put it (the posed pelvis is the rest
    # pelvis + transl, and the rest pelvis is linear in the betas), so only the limbs change with the mean shape.
    shift = pelvis_per_beta(model_dir, gender, len(mean_betas))
    for r, b in zip(records, betas):
        r.params["transl"] = r.params["transl"] + shift @ (b - mean_betas)
    say("import: expression coefficients are ignored: a subject carries no per-frame vertex offsets")
    generator = {"tool": "trioman import smplx-fits", "frames": str(frames_dir.resolve()), "fits": str(fits_dir.resolve()),
                 "gender": gender, "num_betas": len(mean_betas), "flat_hand_mean": flat_hand_mean, "test_every": test_every}
    return write_subject(Path(out), body, records, generator, overwrite=overwrite, up=up, say=say, inputs=inputs)
