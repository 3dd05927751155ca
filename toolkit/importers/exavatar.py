"""Captures in ExAvatar's preprocessed layouts (X-Humans, NeuMan, custom videos) -> a subject folder.

The layouts, as ExAvatar's loaders read them (docs/real_data.md has the full list of files):

- X-Humans: ``SUBJ/{train,test}/TAKE/render/image/color_%06d.png``, ``render/depth/depth_%06d.tiff``
  (mask = depth < the frame's maximum depth), ``render/cameras.npz`` (``intrinsic`` [3, 3], ``extrinsic``
  [F, 4, 4] world -> camera, in image order), ``SMPLX/mesh-f%05d_smplx.pkl`` (pickled, world frame:
  read only with ``allow_pickle``); the splits are the train/test takes.
- NeuMan: ``SEQ/images/%05d.png``, ``masks/N.png`` (training masks), ``segmentations/%05d.png`` (0 = person,
  the evaluation masks, used for test frames), ``sparse/{cameras,images}.txt`` (COLMAP),
  ``smplx_optimized/smplx_params/N.json`` (camera frame; unpadded, as ExAvatar's fitting names them),
  ``{train,test}_split.txt`` (``val_split.txt`` is not read).

Images, masks, fits and cameras are matched by frame number, never by file name, so padding never matters.
- Custom: ``ID/frames/N.png``, ``masks/N.png``, ``smplx_optimized/smplx_params_smoothed/N.json`` (camera
  frame), cameras from ``sparse/`` (COLMAP) or ``cam_params/N.json`` (R, t, focal, princpt),
  ``frame_list_{train,test}.txt``.

Identity: ``smplx_optimized/shape_param.json`` (betas) and, when present, ``face_offset.json`` [10475, 3]
and ``joint_offset.json`` [55, 3]. The body follows ExAvatar's SMPL-X layer: male, 100 shape
coefficients, no hand PCA, hand poses relative to the hand mean. FLAME expression coefficients are not
used (they need the FLAME files, and a subject carries no per-frame vertex offsets).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from trioman.runtime.formats import FormatError, Subject
from trioman.toolkit.body.smplx_model import NUM_JOINTS, NUM_VERTICES, SMPLXBody
from trioman.toolkit.importers.common import (
    FrameRecord, array, files_by_index, images_by_index, read_colmap, read_gray, read_json, read_npz, read_pickle, read_split_list,
    smplx_params, write_subject,
)

DATASETS = ("xhumans", "neuman", "custom")
EXAVATAR_KEYS = {"root": "root_pose", "body": "body_pose", "jaw": "jaw_pose", "leye": "leye_pose",
                 "reye": "reye_pose", "lhand": "lhand_pose", "rhand": "rhand_pose", "transl": "trans"}
XHUMANS_KEYS = {"root": "global_orient", "body": "body_pose", "jaw": "jaw_pose", "leye": "leye_pose",
                "reye": "reye_pose", "lhand": "left_hand_pose", "rhand": "right_hand_pose", "transl": "transl"}
EXPRESSION_NOTE = ("expression coefficients are ignored: FLAME expressions need the FLAME model files, and a "
                   "subject carries no per-frame vertex offsets")


@dataclass(frozen=True)
class BodyConfig:
    """ExAvatar's SMPL-X layer settings by default."""

    model_dir: str
    gender: str = "male"
    num_betas: int = 100
    flat_hand_mean: bool = False


def load_identity(folder: Path, num_betas: int) -> dict[str, np.ndarray | None]:
    """``smplx_optimized/``: shape_param.json [num_betas]; face_offset.json, joint_offset.json when present."""
    shape = folder / "shape_param.json"
    out: dict[str, np.ndarray | None] = {"betas": array(shape, "shape_param", read_json(shape), (num_betas,))}
    for name, size in (("face_offset", (NUM_VERTICES, 3)), ("joint_offset", (NUM_JOINTS, 3))):
        path = folder / f"{name}.json"
        out[name] = array(path, name, read_json(path), size) if path.is_file() else None
    return out


def build_body(cfg: BodyConfig, identity: dict[str, np.ndarray | None]) -> SMPLXBody:
    return SMPLXBody(cfg.model_dir, gender=cfg.gender, num_betas=cfg.num_betas, flat_hand_mean=cfg.flat_hand_mean,
                     betas=identity["betas"], face_offset=identity["face_offset"], joint_offset=identity["joint_offset"])


# --------------------------------------------------------------------------------------------------
# X-Humans


def _depth_mask(path: Path) -> Callable[[], np.ndarray]:
    def read() -> np.ndarray:
        depth = read_gray(path)
        return (depth < depth.max()).astype(np.float32)

    return read


def read_xhumans(subject_dir: Path, allow_pickle: bool) -> list[FrameRecord]:
    records = []
    for split in ("train", "test"):
        split_dir = subject_dir / split
        if not split_dir.is_dir():
            if split == "train":
                raise FormatError(f"{split_dir}: missing folder (X-Humans training takes)")
            continue
        for take in sorted(p for p in split_dir.iterdir() if p.is_dir()):
            render = take / "render"
            images = images_by_index(render / "image", "color_%06d.png images")
            cams_path = render / "cameras.npz"
            cams = read_npz(cams_path)
            for key in ("intrinsic", "extrinsic"):
                if key not in cams:
                    raise FormatError(f"{cams_path}: {key}: missing array")
            intr = array(cams_path, "intrinsic", cams["intrinsic"], (3, 3))
            extr = np.asarray(cams["extrinsic"], dtype=np.float64)
            if extr.ndim != 3 or extr.shape[1:] not in ((4, 4), (3, 4)):
                raise FormatError(f"{cams_path}: extrinsic: expected shape [F, 4, 4], got {list(extr.shape)}")
            if len(extr) != len(images):
                raise FormatError(f"{cams_path}: extrinsic: {len(extr)} cameras for {len(images)} images in "
                                  f"{render / 'image'}")
            extr = array(cams_path, "extrinsic", extr, extr.shape)
            for i, idx in enumerate(sorted(images)):
                depth = render / "depth" / f"depth_{idx:06d}.tiff"
                if not depth.is_file():
                    raise FormatError(f"{depth}: missing file (depth map of {images[idx].name})")
                fit = take / "SMPLX" / f"mesh-f{idx:05d}_smplx.pkl"
                params = smplx_params(fit, read_pickle(fit, allow_pickle), XHUMANS_KEYS)
                records.append(FrameRecord(
                    name=f"{take.name}_{idx:06d}", split=split, sequence=take.name, image=images[idx],
                    mask=_depth_mask(depth), params=params, R=extr[i, :3, :3], t=extr[i, :3, 3],
                    focal=intr[[0, 1], [0, 1]], princpt=intr[[0, 1], [2, 2]]))
    return records


# --------------------------------------------------------------------------------------------------
# NeuMan and custom videos (parameters in the camera frame)


def _binary_mask(path: Path) -> Callable[[], np.ndarray]:
    return lambda: (read_gray(path) > 0.5).astype(np.float32)


def _inverted_mask(path: Path) -> Callable[[], np.ndarray]:
    return lambda: 1.0 - read_gray(path)


def _split_frames(lists: dict[str, Path], required: tuple[str, ...]) -> list[tuple[str, int, Path]]:
    out = []
    for split, path in lists.items():
        if split in required or path.is_file():
            out += [(split, idx, path) for idx in read_split_list(path)]
    return sorted(out, key=lambda s: s[1])


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
        mask = (_inverted_mask(segs[idx]) if split == "test" and idx in segs
                else _binary_mask(_need(masks, idx, seq_dir / "masks", list_path, "mask")))
        records.append(FrameRecord(
            name=image.stem, split=split, sequence=seq_dir.name, image=image, mask=mask,
            params=smplx_params(fit, read_json(fit), EXAVATAR_KEYS), R=cams[idx][0], t=cams[idx][1],
            focal=focal, princpt=princpt, in_camera=True))
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
            focal, princpt = array(cam_path, "focal", cam["focal"], (2,)), array(cam_path, "princpt", cam["princpt"], (2,))
        fit = _need(fits, idx, params_dir, list_path, f"SMPL-X fit ({idx}.json)")
        records.append(FrameRecord(
            name=image.stem, split=split, sequence=video_dir.name, image=image,
            mask=_binary_mask(_need(masks, idx, video_dir / "masks", list_path, "mask")),
            params=smplx_params(fit, read_json(fit), EXAVATAR_KEYS), R=R, t=t, focal=focal, princpt=princpt,
            in_camera=True))
    return records


def import_exavatar(root: str | Path, dataset: str, out: str | Path, body: BodyConfig, subject: str | None = None,
                    allow_pickle: bool = False, overwrite: bool = False, say: Callable[[str], None] = print,
                    up: str = "body") -> Subject:
    """Convert a capture in ExAvatar's layout to a subject folder at ``out`` (nothing is written on error).
    up: where the world's up comes from (``common.upright``: "body", "cameras" or "none")."""
    if dataset not in DATASETS:
        raise ValueError(f"--dataset: unknown dataset {dataset!r}; expected one of {list(DATASETS)}")
    folder = Path(root) / subject if subject else Path(root)
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder}: capture folder not found")
    reader = {"xhumans": lambda: read_xhumans(folder, allow_pickle), "neuman": lambda: read_neuman(folder),
              "custom": lambda: read_custom(folder)}[dataset]
    records = reader()
    smplx_body = build_body(body, load_identity(folder / "smplx_optimized", body.num_betas))
    say(f"import: {EXPRESSION_NOTE}")
    generator = {"tool": "trioman import exavatar", "dataset": dataset, "source": str(folder.resolve()),
                 "gender": body.gender, "num_betas": body.num_betas, "flat_hand_mean": body.flat_hand_mean}
    return write_subject(Path(out), smplx_body, records, generator, overwrite=overwrite, up=up, say=say)
