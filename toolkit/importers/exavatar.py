"""Captures in ExAvatar's preprocessed layouts (X-Humans, NeuMan, custom videos) -> a subject folder.

The layouts as ExAvatar's loaders read them, which fits and masks are used, the identity and the body:
docs/real_data.md, "trioman import exavatar".
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from trioman.runtime.formats import FormatError, Subject
from trioman.toolkit.body.smplx_model import NUM_JOINTS, NUM_VERTICES, SMPLXBody
from trioman.toolkit.importers.common import (
    FrameRecord, array, check_target, files_by_index, focal_array, images_by_index, pelvis_per_beta, read_colmap,
    read_gray, read_json, read_npy, read_npz, read_pickle, read_split_list, smplx_params, write_subject,
)
from trioman.toolkit.importers.options import DATASETS, GENDERS, XHUMANS_FITS, ExAvatarOptions

EXAVATAR_GENDER, EXAVATAR_NUM_BETAS = "male", 100  # ExAvatar's SMPL-X layer
EXAVATAR_KEYS = {"root": "root_pose", "body": "body_pose", "jaw": "jaw_pose", "leye": "leye_pose",
                 "reye": "reye_pose", "lhand": "lhand_pose", "rhand": "rhand_pose", "transl": "trans"}
XHUMANS_KEYS = {"root": "global_orient", "body": "body_pose", "jaw": "jaw_pose", "leye": "leye_pose",
                "reye": "reye_pose", "lhand": "left_hand_pose", "rhand": "right_hand_pose", "transl": "transl"}
EXAVATAR_TAKE_FITS = Path("smplx_optimized") / "smplx_params"  # under an X-Humans take, as ExAvatar's fitting leaves it
EXPRESSION_NOTE = ("expression coefficients are ignored: FLAME expressions need the FLAME model files, and a "
                   "subject carries no per-frame vertex offsets")


@dataclass(frozen=True)
class BodyConfig:
    """The SMPL-X layer settings; None: the fits' own (ExAvatar's male, 100 coefficients; X-Humans' own fits:
    gender.txt and the mean shape's length)."""

    model_dir: str
    gender: str | None = ExAvatarOptions.gender
    num_betas: int | None = ExAvatarOptions.num_betas
    flat_hand_mean: bool = ExAvatarOptions.flat_hand_mean


@dataclass
class Identity:
    """The body the fits were made for: betas and ExAvatar's offsets (SMPL-X frame), the gender when the fits fix
    it, per-frame betas when each fit was made for its own shape (aligned with the records; their translations
    are corrected to ``betas``), and what ``generator.fits`` records."""

    betas: np.ndarray
    face_offset: np.ndarray | None = None
    joint_offset: np.ndarray | None = None
    gender: str | None = None
    frame_betas: list[np.ndarray] | None = None
    fits: dict[str, Any] = field(default_factory=dict)


def load_identity(folder: Path, num_betas: int) -> Identity:
    """``smplx_optimized/``: shape_param.json [num_betas]; face_offset.json, joint_offset.json when present."""
    shape = folder / "shape_param.json"
    out = Identity(betas=array(shape, "shape_param", read_json(shape), (num_betas,)))
    for name, size in (("face_offset", (NUM_VERTICES, 3)), ("joint_offset", (NUM_JOINTS, 3))):
        path = folder / f"{name}.json"
        setattr(out, name, array(path, name, read_json(path), size) if path.is_file() else None)
    return out


def _same_identity(a: Identity, b: Identity) -> bool:
    def same(x: np.ndarray | None, y: np.ndarray | None) -> bool:
        return (x is None and y is None) or (x is not None and y is not None and np.array_equal(x, y))

    return same(a.betas, b.betas) and same(a.face_offset, b.face_offset) and same(a.joint_offset, b.joint_offset)


# --------------------------------------------------------------------------------------------------
# X-Humans


def _depth_mask(path: Path) -> Callable[[], np.ndarray]:
    def read() -> np.ndarray:
        depth = read_gray(path)
        return (depth < depth.max()).astype(np.float32)

    return read


def _xhumans_takes(subject_dir: Path) -> list[tuple[str, Path]]:
    """(split, take folder) of every take, train first, by name."""
    takes = []
    for split in ("train", "test"):
        split_dir = subject_dir / split
        if not split_dir.is_dir():
            if split == "train":
                raise FormatError(f"{split_dir}: missing folder (X-Humans training takes)")
            continue
        takes += [(split, take) for take in sorted(p for p in split_dir.iterdir() if p.is_dir())]
    return takes


def _take_frames(take: Path) -> list[tuple[int, Path, Path, np.ndarray, np.ndarray, np.ndarray]]:
    """A take's frames: (frame number, image, depth map, intrinsic [3, 3], R [3, 3], t [3]), in image order."""
    render = take / "render"
    images = images_by_index(render / "image", "color_%06d.png images")
    cams_path = render / "cameras.npz"
    cams = read_npz(cams_path)
    for key in ("intrinsic", "extrinsic"):
        if key not in cams:
            raise FormatError(f"{cams_path}: {key}: missing array")
    intr = array(cams_path, "intrinsic", cams["intrinsic"], (3, 3))
    focal_array(cams_path, "intrinsic: fx, fy", intr[[0, 1], [0, 1]])
    extr = np.asarray(cams["extrinsic"], dtype=np.float64)
    if extr.ndim != 3 or extr.shape[1:] not in ((4, 4), (3, 4)):
        raise FormatError(f"{cams_path}: extrinsic: expected shape [F, 4, 4], got {list(extr.shape)}")
    if len(extr) != len(images):
        raise FormatError(f"{cams_path}: extrinsic: {len(extr)} cameras for {len(images)} images in {render / 'image'}")
    extr = array(cams_path, "extrinsic", extr, extr.shape)
    out = []
    for i, idx in enumerate(sorted(images)):  # cameras in image order, as ExAvatar's loaders pair them
        depth = render / "depth" / f"depth_{idx:06d}.tiff"
        if not depth.is_file():
            raise FormatError(f"{depth}: missing file (depth map of {images[idx].name})")
        out.append((idx, images[idx], depth, intr, extr[i, :3, :3], extr[i, :3, 3]))
    return out


def _xhumans_body(subject_dir: Path) -> tuple[str, np.ndarray]:
    """X-Humans' own body: gender.txt's gender (its first line) and mean_shape_smplx.npy's betas."""
    gender_path, shape_path = subject_dir / "gender.txt", subject_dir / "mean_shape_smplx.npy"
    if not gender_path.is_file():
        raise FormatError(f"{gender_path}: missing file (X-Humans' subject gender, which its fits were made for)")
    lines = gender_path.read_text(encoding="utf-8", errors="replace").splitlines()
    gender = lines[0].strip() if lines else ""
    if gender not in GENDERS:
        raise FormatError(f"{gender_path}: expected one of {list(GENDERS)} on the first line, got {gender!r}")
    raw = read_npy(shape_path)
    betas = array(shape_path, "betas", raw, (np.size(raw),))
    if not 1 <= betas.size <= 300:
        raise FormatError(f"{shape_path}: betas: expected 1 to 300 shape coefficients, got {betas.size}")
    return gender, betas


def read_xhumans(subject_dir: Path, allow_pickle: bool, fits: str = "auto", num_betas: int = EXAVATAR_NUM_BETAS,
                 say: Callable[[str], None] = print) -> tuple[list[FrameRecord], Identity]:
    """The takes' frames, posed by fits that belong to the body they pose (``fits``: ``XHUMANS_FITS``), and that
    body. Says once which fits and body are used."""
    if fits not in XHUMANS_FITS:
        raise ValueError(f"fits: expected one of {list(XHUMANS_FITS)}, got {fits!r}")
    takes = _xhumans_takes(subject_dir)
    fitted = [(split, take) for split, take in takes if (take / EXAVATAR_TAKE_FITS).is_dir()]
    unfitted = [take.name for _, take in takes if not (take / EXAVATAR_TAKE_FITS).is_dir()]
    source = fits if fits != "auto" else ("exavatar" if fitted and not unfitted else "xhumans")
    records: list[FrameRecord] = []
    if source == "exavatar":
        if not fitted:
            raise FormatError(f"{subject_dir}: `fits` exavatar: no take holds ExAvatar's fitting output "
                              f"(TAKE/{EXAVATAR_TAKE_FITS.as_posix()}/N.json)")
        identity, first = None, None
        for split, take in fitted:
            opt = take / EXAVATAR_TAKE_FITS.parent
            this = load_identity(opt, num_betas)
            if identity is None:
                identity, first = this, opt
            elif not _same_identity(identity, this):
                raise FormatError(f"{opt}: another identity than {first} (shape_param, face_offset or joint_offset "
                                  f"differ): the takes were fitted separately, and a subject has one body; keep one "
                                  f"identity's fits")
            params_dir = take / EXAVATAR_TAKE_FITS
            found = files_by_index(params_dir, (".json",), "SMPL-X fits (FRAME.json)")
            frames = _take_frames(take)
            extra = sorted(set(found) - {f[0] for f in frames})
            if extra:
                raise FormatError(f"{found[extra[0]]}: a fit for frame {extra[0]}, which has no image in "
                                  f"{take / 'render' / 'image'} (ExAvatar's fitting writes one per image of the take)")
            for idx, image, depth, intr, R, t in frames:
                if idx not in found:
                    raise FormatError(f"{params_dir}: no fit for frame {idx} ({image.name}): ExAvatar's fitting "
                                      f"writes one per image of the take ({idx}.json)")
                fit = found[idx]
                records.append(FrameRecord(
                    name=f"{take.name}_{idx:06d}", split=split, sequence=take.name, image=image,
                    mask=_depth_mask(depth), params=smplx_params(fit, read_json(fit), EXAVATAR_KEYS), R=R, t=t,
                    focal=intr[[0, 1], [0, 1]], princpt=intr[[0, 1], [2, 2]], in_camera=True, mask_file=depth))
        assert identity is not None and first is not None
        identity.fits = {"source": "exavatar", "files": f"TAKE/{EXAVATAR_TAKE_FITS.as_posix()}/N.json",
                         "identity": str(first.relative_to(subject_dir)), "takes": [t.name for _, t in fitted],
                         "left_out": unfitted}
        left = f"; left out, holding none: {', '.join(unfitted)}" if unfitted else ""
        say(f"import: X-Humans: posed by ExAvatar's fits of {len(fitted)} take(s) ({', '.join(t.name for _, t in fitted)}: "
            f"TAKE/{EXAVATAR_TAKE_FITS.as_posix()}/N.json, camera frame) on their identity ({first.relative_to(subject_dir)}"
            f"/shape_param.json, {identity.betas.size} betas){left}")
        return records, identity

    gender, mean_betas = _xhumans_body(subject_dir)
    frame_betas = []
    for split, take in takes:
        for idx, image, depth, intr, R, t in _take_frames(take):
            fit = take / "SMPLX" / f"mesh-f{idx:05d}_smplx.pkl"
            data = read_pickle(fit, allow_pickle)
            params = smplx_params(fit, data, XHUMANS_KEYS)
            b = data.get("betas") if isinstance(data, dict) else None
            frame_betas.append(mean_betas if b is None else array(fit, "betas", b, mean_betas.shape))
            records.append(FrameRecord(
                name=f"{take.name}_{idx:06d}", split=split, sequence=take.name, image=image, mask=_depth_mask(depth),
                params=params, R=R, t=t, focal=intr[[0, 1], [0, 1]], princpt=intr[[0, 1], [2, 2]], mask_file=depth))
    identity = Identity(betas=mean_betas, gender=gender, frame_betas=frame_betas, fits={
        "source": "xhumans", "files": "TAKE/SMPLX/mesh-fNNNNN_smplx.pkl", "identity": "gender.txt, mean_shape_smplx.npy",
        "takes": [t.name for _, t in takes], "left_out": []})
    if fitted:
        why = (f"only {len(fitted)} of {len(takes)} takes hold ExAvatar's fitting output ({', '.join(unfitted)} "
               f"{'has' if len(unfitted) == 1 else 'have'} none; `fits` exavatar imports only those)" if unfitted
               else "`fits` xhumans")
    else:
        why = f"no take holds ExAvatar's fitting output (TAKE/{EXAVATAR_TAKE_FITS.as_posix()}/N.json)"
    unused = (f"; {subject_dir.name}/smplx_optimized (ExAvatar's identity) is not used: these fits were not made for it"
              if (subject_dir / "smplx_optimized").is_dir() else "")
    say(f"import: X-Humans: posed by X-Humans' own fits (TAKE/SMPLX/*.pkl) on X-Humans' own body ({gender}, gender.txt; "
        f"{mean_betas.size} betas, mean_shape_smplx.npy): {why}{unused}")
    return records, identity


# --------------------------------------------------------------------------------------------------
# NeuMan and custom videos (parameters in the camera frame)


def _binary_mask(path: Path) -> Callable[[], np.ndarray]:
    return lambda: (read_gray(path) > 0.5).astype(np.float32)


def _inverted_mask(path: Path) -> Callable[[], np.ndarray]:
    return lambda: 1.0 - read_gray(path)


def _split_frames(lists: dict[str, Path], required: tuple[str, ...]) -> list[tuple[str, int, Path]]:
    """(split, frame number, list file) of every listed frame, by frame number; a frame in two lists -> FormatError."""
    listed: dict[int, tuple[str, Path]] = {}
    for split, path in lists.items():
        if split in required or path.is_file():
            for idx in read_split_list(path):
                if idx in listed:
                    raise FormatError(f"{path}: frame {idx} is also in {listed[idx][1]}; a frame belongs to one split")
                listed[idx] = (split, path)
    return [(split, idx, path) for idx, (split, path) in sorted(listed.items())]


def _need(table: dict[int, Path], idx: int, folder: Path, list_path: Path, what: str) -> Path:
    if idx not in table:
        raise FormatError(f"{list_path}: frame {idx}: no {what} in {folder}")
    return table[idx]


def read_neuman(seq_dir: Path) -> list[FrameRecord]:
    images = images_by_index(seq_dir / "images", "images")
    masks = images_by_index(seq_dir / "masks", "masks")
    segs = images_by_index(seq_dir / "segmentations", "segmentations") if (seq_dir / "segmentations").is_dir() else {}
    focal, princpt, cams = read_colmap(seq_dir / "sparse")
    params_dir = seq_dir / "smplx_optimized" / "smplx_params"
    fits = files_by_index(params_dir, (".json",), "SMPL-X fits (FRAME.json)")
    records = []
    lists = {"train": seq_dir / "train_split.txt", "test": seq_dir / "test_split.txt"}
    for split, idx, list_path in _split_frames(lists, ("train",)):
        image = _need(images, idx, seq_dir / "images", list_path, "image")
        if idx not in cams:
            raise FormatError(f"{list_path}: frame {idx}: no camera for {image.name} in {seq_dir / 'sparse' / 'images.txt'}")
        fit = _need(fits, idx, params_dir, list_path, f"SMPL-X fit ({idx}.json)")
        if split == "test" and idx in segs:  # NeuMan's evaluation masks, as ExAvatar evaluates
            mask_file, mask = segs[idx], _inverted_mask(segs[idx])
        else:
            mask_file = _need(masks, idx, seq_dir / "masks", list_path, "mask")
            mask = _binary_mask(mask_file)
        records.append(FrameRecord(
            name=image.stem, split=split, sequence=seq_dir.name, image=image, mask=mask,
            params=smplx_params(fit, read_json(fit), EXAVATAR_KEYS), R=cams[idx][0], t=cams[idx][1],
            focal=focal, princpt=princpt, in_camera=True, mask_file=mask_file))
    return records


def read_custom(video_dir: Path) -> list[FrameRecord]:
    images = images_by_index(video_dir / "frames", "frames")
    masks = images_by_index(video_dir / "masks", "masks")
    params_dir = video_dir / "smplx_optimized" / "smplx_params_smoothed"
    fits = files_by_index(params_dir, (".json",), "SMPL-X fits (FRAME.json)")
    colmap = read_colmap(video_dir / "sparse") if (video_dir / "sparse" / "cameras.txt").is_file() else None
    cam_files = files_by_index(video_dir / "cam_params", (".json",), "camera files (FRAME.json)") if colmap is None else {}
    records = []
    lists = {"train": video_dir / "frame_list_train.txt", "test": video_dir / "frame_list_test.txt"}
    for split, idx, list_path in _split_frames(lists, ("train",)):
        image = _need(images, idx, video_dir / "frames", list_path, "frame")
        if colmap is not None:
            focal, princpt, cams = colmap
            if idx not in cams:
                raise FormatError(f"{list_path}: frame {idx}: no camera in {video_dir / 'sparse' / 'images.txt'}")
            R, t = cams[idx]
        else:
            cam_path = _need(cam_files, idx, video_dir / "cam_params", list_path, f"camera ({idx}.json)")
            cam = read_json(cam_path)
            if not isinstance(cam, dict):
                raise FormatError(f"{cam_path}: expected an object with R, t, focal, princpt")
            for key in ("R", "t", "focal", "princpt"):
                if key not in cam:
                    raise FormatError(f"{cam_path}: {key}: missing field")
            R, t = array(cam_path, "R", cam["R"], (3, 3)), array(cam_path, "t", cam["t"], (3,))
            focal, princpt = focal_array(cam_path, "focal", cam["focal"]), array(cam_path, "princpt", cam["princpt"], (2,))
        fit = _need(fits, idx, params_dir, list_path, f"SMPL-X fit ({idx}.json)")
        mask_file = _need(masks, idx, video_dir / "masks", list_path, "mask")
        records.append(FrameRecord(
            name=image.stem, split=split, sequence=video_dir.name, image=image, mask=_binary_mask(mask_file),
            params=smplx_params(fit, read_json(fit), EXAVATAR_KEYS), R=R, t=t, focal=focal, princpt=princpt,
            in_camera=True, mask_file=mask_file))
    return records


def _resolve_body(body: BodyConfig, identity: Identity, folder: Path) -> tuple[str, int]:
    """(gender, num_betas) of the layer: the fits' own; a ``gender`` or ``num_betas`` that would pose another body with
    them is refused."""
    if identity.gender is None:
        return body.gender or EXAVATAR_GENDER, identity.betas.size
    for name, given, own, where in (("gender", body.gender, identity.gender, "gender.txt"),
                                    ("num_betas", body.num_betas, identity.betas.size, "mean_shape_smplx.npy")):
        if given is not None and given != own:
            raise ValueError(f"{name} {given}: X-Humans' own fits were made for its own body, whose value is {own} "
                             f"({folder / where}); drop `{name}`, or give ExAvatar's fits (TAKE/"
                             f"{EXAVATAR_TAKE_FITS.as_posix()}/) with `fits` exavatar")
    return identity.gender, identity.betas.size


def import_exavatar(root: str | Path, dataset: str, out: str | Path, body: BodyConfig, subject: str | None = None,
                    allow_pickle: bool = ExAvatarOptions.allow_pickle, overwrite: bool = False,
                    say: Callable[[str], None] = print, up: str = ExAvatarOptions.up,
                    fits: str = ExAvatarOptions.fits) -> Subject:
    """Convert a capture in ExAvatar's layout to a subject folder at ``out`` (nothing is written on error; ``out``
    is checked before anything is read). up: where the world's up comes from (``common.upright``: "body",
    "cameras" or "none"); fits: X-Humans' fit source (``XHUMANS_FITS``)."""
    if dataset not in DATASETS:
        raise ValueError(f"dataset: unknown dataset {dataset!r}; expected one of {list(DATASETS)}")
    if fits not in XHUMANS_FITS or (fits != "auto" and dataset != "xhumans"):
        raise ValueError(f"fits {fits}: expected one of {list(XHUMANS_FITS)}, and only with `dataset` xhumans")
    folder = Path(root) / subject if subject else Path(root)
    check_target(out, overwrite, [folder])
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder}: capture folder not found")
    num_betas = body.num_betas or EXAVATAR_NUM_BETAS
    if dataset == "xhumans":
        records, identity = read_xhumans(folder, allow_pickle, fits, num_betas, say)
    else:
        records = read_neuman(folder) if dataset == "neuman" else read_custom(folder)
        identity = load_identity(folder / "smplx_optimized", num_betas)
        fits_dir = "smplx_optimized/" + ("smplx_params" if dataset == "neuman" else "smplx_params_smoothed")
        identity.fits = {"source": "exavatar", "files": f"{fits_dir}/N.json", "identity": "smplx_optimized"}
    gender, num_betas = _resolve_body(body, identity, folder)
    if identity.frame_betas is not None and any(not np.array_equal(b, identity.betas) for b in identity.frame_betas):
        # each fit was made for its own betas: keep its pelvis there under the one shape (only the limbs follow it)
        shift = pelvis_per_beta(body.model_dir, gender, num_betas)
        for r, b in zip(records, identity.frame_betas):
            r.params["transl"] = r.params["transl"] + shift @ (b - identity.betas)
    smplx_body = SMPLXBody(body.model_dir, gender=gender, num_betas=num_betas, flat_hand_mean=body.flat_hand_mean,
                           betas=identity.betas, face_offset=identity.face_offset, joint_offset=identity.joint_offset)
    say(f"import: {EXPRESSION_NOTE}")
    generator = {"tool": "trioman import exavatar", "dataset": dataset, "source": str(folder.resolve()),
                 "gender": gender, "num_betas": num_betas, "flat_hand_mean": body.flat_hand_mean, "fits": identity.fits}
    return write_subject(Path(out), smplx_body, records, generator, overwrite=overwrite, up=up, say=say,
                         inputs=(folder,))
