"""The subject format (version 1), a folder: ``load_subject`` validates everything and raises ``FormatError``
naming the file, the field and the value; ``save_subject`` writes atomically. The layout: docs/formats.md,
"Subject".
"""

from __future__ import annotations

import json
import operator
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Mapping

import numpy as np

from trioman.runtime.image_io import encode_png, png_header, read_png
from trioman.runtime.outputs import FolderKind, atomic_folder, check_folder_target, known_kind, write_synced
from trioman.runtime.formats.common import (
    FormatError,
    as_real,
    check_header,
    format_error,
    is_int,
    is_number,
    load_json,
    load_npz,
    plain_json,
    write_npz,
)
from trioman.runtime.skeleton import SkinnedMesh
from trioman.runtime.inspect import InspectOptions

SUBJECT_FORMAT = "trioman-subject"
SUBJECT_VERSION = 1
SPLITS = ("train", "test")

SUBJECT_JSON = "subject.json"
BODY_NPZ = "body.npz"
FRAMES_NPZ = "frames.npz"
IMAGES_DIR = "images"
MASKS_DIR = "masks"
WEIGHTS_DIR = "weights"  # optional: per-pixel loss weights of every frame (8-bit, 255 = 1), trioman augment's aligned pseudo-GT

# Tolerances for camera checks (the arrays are stored as float32).
ORTHONORMAL_TOL = 1e-3  # max |R R^T - I|
LAST_ROW_TOL = 1e-6

CONTACT_SHEET_PNG = "contact_sheet.png"  # written beside a subject by trioman synth
FIT_REPORT_FILES = ("fit.json", "fit.md", "fit_overlay.png", "fit_overlay.mp4")  # written beside a subject by trioman fit
# What --overwrite may replace (outputs.check_folder_target): a folder of exactly these files.
SUBJECT_FOLDER = known_kind(FolderKind("subject", SUBJECT_JSON, files=(SUBJECT_JSON, BODY_NPZ, FRAMES_NPZ, CONTACT_SHEET_PNG, *FIT_REPORT_FILES),
                            folders=((IMAGES_DIR, ("*.png",)), (MASKS_DIR, ("*.png",))), format=SUBJECT_FORMAT))

_FRAME_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.\-]{0,199}")  # fullmatch: "$" would pass a final newline
_FLOAT_ARRAYS = ("poses", "trans", "K", "viewmat")
_STRING_ARRAYS = ("split", "sequence", "frame_names")
FRAME_ARRAYS = _FLOAT_ARRAYS + _STRING_ARRAYS + ("poses_true",)  # every array frames.npz may hold


@dataclass(frozen=True, eq=False)
class Subject:
    """A loaded subject folder. Arrays are read-only; images and masks are read on demand."""

    root: Path
    meta: dict[str, Any]  # subject.json
    body: SkinnedMesh  # shaped body, rest pose
    poses: np.ndarray  # [N, J, 3] float32 axis-angle per joint (stored, possibly noisy "fitted" poses)
    trans: np.ndarray  # [N, 3] float32 root translation (m)
    K: np.ndarray  # [N, 3, 3] float32 intrinsics (pixels)
    viewmat: np.ndarray  # [N, 4, 4] float32 world -> camera (OpenCV)
    split: np.ndarray  # [N] str, "train" or "test"
    sequence: np.ndarray  # [N] str, the motion sequence of each frame
    frame_names: np.ndarray  # [N] str, file stem of images/<name>.png and masks/<name>.png
    poses_true: np.ndarray | None = None  # [N, J, 3] float32 ground-truth poses when recorded

    @property
    def width(self) -> int:
        return int(self.meta["width"])

    @property
    def height(self) -> int:
        return int(self.meta["height"])

    @property
    def num_frames(self) -> int:
        return len(self.poses)

    @property
    def num_joints(self) -> int:
        return self.body.skeleton.num_joints

    @property
    def body_model(self) -> str:
        return str(self.meta["body_model"])

    @property
    def sequences(self) -> tuple[str, ...]:
        return tuple(self.meta["sequences"])

    @property
    def background(self) -> np.ndarray:
        """[3] float32 RGB in [0, 1]."""
        return np.asarray(self.meta["background"], dtype=np.float32)

    def indices(self, split: str | None = None, sequence: str | None = None) -> np.ndarray:
        """Frame indices [M] int64 (ascending) of a split ("train"/"test") and/or a sequence; None = all."""
        keep = np.ones(self.num_frames, dtype=bool)
        if split is not None:
            if split not in SPLITS:
                raise ValueError(f"split: expected one of {list(SPLITS)}, got {split!r}")
            keep &= self.split == split
        if sequence is not None:
            if sequence not in self.sequences:
                raise ValueError(f"sequence: unknown sequence {sequence!r} (subject has {list(self.sequences)})")
            keep &= self.sequence == sequence
        return np.flatnonzero(keep)

    def _index(self, i: int) -> int:
        n = self.num_frames
        i = operator.index(i)
        if not -n <= i < n:
            raise IndexError(f"frame index: {i} out of range for {n} frames")
        return i % n

    def image_path(self, i: int) -> Path:
        return self.root / IMAGES_DIR / f"{self.frame_names[self._index(i)]}.png"

    def mask_path(self, i: int) -> Path:
        return self.root / MASKS_DIR / f"{self.frame_names[self._index(i)]}.png"

    def image(self, i: int) -> np.ndarray:
        """Frame i as float32 RGB [H, W, 3] in [0, 1]."""
        return self._read(self.image_path(i), "rgb")

    def mask(self, i: int) -> np.ndarray:
        """Mask of frame i as float32 [H, W] in [0, 1] (1 = subject)."""
        return self._read(self.mask_path(i), "gray")

    def _read(self, path: Path, mode: str) -> np.ndarray:
        try:
            img = read_png(path, mode=mode)
        except FileNotFoundError:
            raise FormatError(f"{path}: missing file") from None
        except ValueError as err:
            raise FormatError(str(err)) from None
        if img.shape[:2] != (self.height, self.width):
            raise FormatError(
                f"{path}: image size {img.shape[1]}x{img.shape[0]} (W x H) does not match "
                f"subject.json width x height {self.width}x{self.height}"
            )
        return img

    def camera_centers(self) -> np.ndarray:
        """[N, 3] float64 camera centres in world coordinates (-R^T t)."""
        R = self.viewmat[:, :3, :3].astype(np.float64)
        t = self.viewmat[:, :3, 3].astype(np.float64)
        return -np.einsum("nji,nj->ni", R, t)

    def posed_vertices(self, i: int, true_pose: bool = False) -> np.ndarray:
        """[V, 3] float64 world vertices of frame i (stored pose, or poses_true when asked)."""
        i = self._index(i)
        poses = self.poses if not true_pose else self.poses_true
        if poses is None:
            raise ValueError("poses_true: this subject records no ground-truth poses")
        return self.body.pose(poses[i], self.trans[i])


# --------------------------------------------------------------------------------------------------
# validation helpers (shared by load and save; ``where`` is the file path or "save_subject")


MAX_SIDE = 8192  # a subject's frames' longest side (pixels): an 8K frame


def check_subject_meta(meta: Any, where: Any) -> dict[str, Any]:
    get = check_header(meta, where, SUBJECT_FORMAT, SUBJECT_VERSION, "subject")
    if get("up_axis") != "z":
        raise format_error(where, "up_axis", f"expected 'z', got {meta['up_axis']!r}")
    for field in ("width", "height", "num_frames"):
        v = get(field)
        if not is_int(v) or v <= 0:
            raise format_error(where, field, f"expected a positive integer, got {v!r}")
        if field != "num_frames" and v > MAX_SIDE:
            raise format_error(where, field, f"{v} pixels, more than the {MAX_SIDE} a subject may have "
                                             f"(an 8K frame's; scale the frames down)")
    bg = get("background")
    if not (isinstance(bg, list) and len(bg) == 3 and all(is_number(c) and 0.0 <= c <= 1.0 for c in bg)):
        raise format_error(where, "background", f"expected [r, g, b] with values in [0, 1], got {bg!r}")
    phenotype = get("phenotype")
    if not isinstance(phenotype, dict):
        raise format_error(where, "phenotype", f"expected an object of name -> number, got {type(phenotype).__name__}")
    for k, v in phenotype.items():
        if not is_number(v):
            raise format_error(where, f"phenotype.{k}", f"expected a finite number, got {v!r}")
    if not isinstance(get("generator"), dict):
        raise format_error(where, "generator", f"expected an object, got {type(meta['generator']).__name__}")
    if "capture_to_world" in meta:  # optional: imported captures
        _check_capture_to_world(meta["capture_to_world"], where)
    seqs = get("sequences")
    if not (isinstance(seqs, list) and seqs and all(isinstance(s, str) and s for s in seqs)):
        raise format_error(where, "sequences", f"expected a non-empty list of non-empty names, got {seqs!r}")
    if len(set(seqs)) != len(seqs):
        dup = sorted({s for s in seqs if seqs.count(s) > 1})
        raise format_error(where, "sequences", f"duplicate name(s) {dup}")
    return meta


def _check_capture_to_world(value: Any, where: Any) -> None:
    """A rotation matrix [3, 3] as nested lists: orthonormal within 1e-6, determinant +1."""
    ok = (isinstance(value, list) and len(value) == 3
          and all(isinstance(row, list) and len(row) == 3 and all(is_number(v) for v in row) for row in value))
    if not ok:
        raise format_error(where, "capture_to_world", f"expected a 3 x 3 rotation matrix (lists of numbers), got {value!r}")
    R = np.asarray(value, dtype=np.float64)
    if np.abs(R @ R.T - np.eye(3)).max() > 1e-6 or np.linalg.det(R) < 0:
        raise format_error(where, "capture_to_world", "not a rotation (R R^T != I or det(R) = -1)")


def check_frames(
    arrays: Mapping[str, np.ndarray], where: Any, num_frames: int, num_joints: int, sequences: list[str]
) -> dict[str, np.ndarray]:
    """Validate the frame arrays; return them cast (float32 / str) and read-only."""
    out: dict[str, np.ndarray] = {}
    N, J = num_frames, num_joints
    shapes = {"poses": (N, J, 3), "trans": (N, 3), "K": (N, 3, 3), "viewmat": (N, 4, 4), "poses_true": (N, J, 3)}
    for key in FRAME_ARRAYS:
        if key not in arrays or arrays[key] is None:
            if key == "poses_true":
                continue
            raise format_error(where, key, f"missing array (has: {sorted(k for k in arrays if arrays[k] is not None)})")
        a = np.asarray(arrays[key])
        if key in _STRING_ARRAYS:
            if a.dtype.kind != "U":
                raise format_error(where, key, f"expected a unicode string array, got dtype {a.dtype}")
            if a.ndim != 1:
                raise format_error(where, key, f"expected shape [N] = [{N}], got {list(a.shape)}")
        else:
            if a.dtype.kind not in "fiu":
                raise format_error(where, key, f"expected a float array, got dtype {a.dtype}")
            want = shapes[key]
            if a.ndim != len(want) or a.shape[1:] != want[1:]:
                if key in ("poses", "poses_true") and a.ndim == 3 and a.shape[2] == 3:
                    raise format_error(where, key, f"{a.shape[1]} joints per frame, but body.npz has {J} joints")
                shown = "[" + ", ".join(["N"] + [str(s) for s in want[1:]]) + "]"
                raise format_error(where, key, f"expected shape {shown}, got {list(a.shape)}")
            a = a.astype(np.float32)
            bad = ~np.isfinite(a)
            if bad.any():
                first = int(np.flatnonzero(bad.reshape(len(a), -1).any(axis=1))[0])
                raise format_error(where, key, f"{int(bad.sum())} non-finite value(s) (NaN/Inf), first in frame {first}")
        if len(a) != N:
            raise format_error(where, key, f"{len(a)} frames, but subject.json num_frames is {N}")
        a.setflags(write=False)
        out[key] = a

    K, viewmat = out["K"], out["viewmat"]
    focal = np.minimum(K[:, 0, 0], K[:, 1, 1])
    if np.any(focal <= 0):
        i = int(np.flatnonzero(focal <= 0)[0])
        raise format_error(where, "K", f"non-positive focal length in frame {i}: fx={K[i, 0, 0]}, fy={K[i, 1, 1]}")
    bottom = np.abs(K[:, 2] - np.array([0, 0, 1], np.float32)).max(axis=1)
    if np.any(bottom > LAST_ROW_TOL) or np.any(K[:, 1, 0] != 0):
        i = int(np.flatnonzero((bottom > LAST_ROW_TOL) | (K[:, 1, 0] != 0))[0])
        raise format_error(where, "K", f"frame {i}: expected [[fx, s, cx], [0, fy, cy], [0, 0, 1]], got {K[i].tolist()}")
    last = np.abs(viewmat[:, 3] - np.array([0, 0, 0, 1], np.float32)).max(axis=1)
    if np.any(last > LAST_ROW_TOL):
        i = int(np.flatnonzero(last > LAST_ROW_TOL)[0])
        raise format_error(where, "viewmat", f"frame {i}: last row must be [0, 0, 0, 1], got {viewmat[i, 3].tolist()}")
    R = viewmat[:, :3, :3].astype(np.float64)
    ortho = np.abs(R @ np.swapaxes(R, 1, 2) - np.eye(3)).max(axis=(1, 2))
    det = np.linalg.det(R)
    bad = (ortho > ORTHONORMAL_TOL) | (det <= 0)
    if np.any(bad):
        i = int(np.flatnonzero(bad)[0])
        raise format_error(
            where, "viewmat",
            f"frame {i}: rotation is not orthonormal with det +1 (max |R R^T - I| = {ortho[i]:.3g}, det = {det[i]:.4g})",
        )

    split = out["split"]
    wrong = sorted(set(split.tolist()) - set(SPLITS))
    if wrong:
        raise format_error(where, "split", f"values must be 'train' or 'test', got {wrong} ({int(np.isin(split, wrong).sum())} frames)")
    seq = out["sequence"]
    used = set(seq.tolist())
    unknown = sorted(used - set(sequences))
    if unknown:
        raise format_error(where, "sequence", f"name(s) {unknown} not listed in subject.json sequences {sequences}")
    unused = [s for s in sequences if s not in used]
    if unused:
        raise format_error(where, "sequence", f"subject.json lists sequence(s) {unused} that no frame uses")
    names = out["frame_names"].tolist()
    for i, name in enumerate(names):
        check_frame_name(name, where, f"frame_names: frame {i}")
    if len(set(names)) != len(names):
        dup = sorted({n for n in names if names.count(n) > 1})[:5]
        raise format_error(where, "frame_names", f"duplicate name(s) {dup}")
    return out


def check_frame_name(name: Any, where: Any, field: str) -> str:
    """The one rule of a frame name, wherever it comes from (frames.npz, an augment record): a file stem of
    letters, digits, '_', '-' and '.', not starting with '.', at most 200 characters, so ``images/<name>.png``
    stays inside its folder. -> ``name``; a FormatError naming ``where`` and ``field`` otherwise."""
    if not (isinstance(name, str) and _FRAME_NAME.fullmatch(name)):
        raise format_error(where, field, f"{name!r} is not a safe file stem (letters, digits, '_', '-', '.')")
    return name


# --------------------------------------------------------------------------------------------------
# load


def load_subject(path: str | os.PathLike, check_images: bool = InspectOptions.check_images) -> Subject:
    """Load and validate a subject folder (see docs/formats.md).

    check_images: also check that every frame's image and mask exist, are PNGs of the right kind and
    have the size of subject.json (reads only each file's 33-byte header). Raises FormatError.
    """
    root = Path(path)
    if not root.exists():
        raise FormatError(f"{root}: subject folder not found")
    if not root.is_dir():
        raise FormatError(f"{root}: not a folder (a subject is a folder with {SUBJECT_JSON}, {BODY_NPZ}, {FRAMES_NPZ}, {IMAGES_DIR}/, {MASKS_DIR}/)")
    meta_path = root / SUBJECT_JSON
    meta = check_subject_meta(load_json(meta_path), meta_path)

    body_path = root / BODY_NPZ
    body_arrays = load_npz(body_path)
    try:
        body = SkinnedMesh.from_arrays(body_arrays)
    except (ValueError, KeyError, TypeError) as err:
        raise FormatError(f"{body_path}: {err}") from None

    frames_path = root / FRAMES_NPZ
    N, J = meta["num_frames"], body.skeleton.num_joints
    longest = max(200, *(len(s) for s in meta["sequences"]))  # characters of a frame or sequence name
    max_bytes = N * max(J * 3 * 8, 16 * 8, 4 * longest) + 4096  # float64 poses, viewmat, UCS-4 names; header
    frames = check_frames(load_npz(frames_path, FRAME_ARRAYS, max_bytes), frames_path, N, J, meta["sequences"])
    subject = Subject(root=root, meta=meta, body=body, **frames)
    if check_images:
        _check_image_files(subject)
    return subject


def _check_image_files(subject: Subject) -> None:
    W, H = subject.width, subject.height
    for folder, kind, channels in ((IMAGES_DIR, "image", (3, 4)), (MASKS_DIR, "mask", (1,))):
        d = subject.root / folder
        if not d.is_dir():
            raise FormatError(f"{d}: missing folder ({subject.num_frames} frame {kind}s expected)")
        for i, name in enumerate(subject.frame_names.tolist()):
            p = d / f"{name}.png"
            try:
                w, h, c = png_header(p)
            except FileNotFoundError:
                raise FormatError(f"{p}: missing {kind} for frame {name!r} (index {i})") from None
            except ValueError as err:
                raise FormatError(f"{err} ({kind} of frame {name!r})") from None
            if (w, h) != (W, H):
                raise FormatError(
                    f"{p}: {kind} size {w}x{h} (W x H) does not match subject.json width x height {W}x{H} (frame {name!r})"
                )
            if c not in channels:
                want = "an RGB" if kind == "image" else "a single-channel gray"
                raise FormatError(f"{p}: expected {want} PNG, got {c} channel(s) (frame {name!r})")


# --------------------------------------------------------------------------------------------------
# save


def save_subject(
    path: str | os.PathLike,
    *,
    body: SkinnedMesh,
    poses: np.ndarray,  # [N, J, 3] axis-angle
    trans: np.ndarray,  # [N, 3]
    K: np.ndarray,  # [N, 3, 3]
    viewmat: np.ndarray,  # [N, 4, 4] world -> camera
    split: Iterable[str],  # [N] "train" | "test"
    sequence: Iterable[str],  # [N]
    images: Iterable[np.ndarray],  # N x float32 RGB [H, W, 3] in [0, 1]
    masks: Iterable[np.ndarray],  # N x float32 [H, W] in [0, 1]
    width: int,
    height: int,
    body_model: str,
    background: Iterable[float] = (0.0, 0.0, 0.0),
    phenotype: Mapping[str, float] | None = None,
    generator: Mapping[str, Any] | None = None,
    frame_names: Iterable[str] | None = None,  # [N], default "000000", "000001", ...
    poses_true: np.ndarray | None = None,  # [N, J, 3]
    overwrite: bool = False,
    inputs: Iterable[str | os.PathLike | None] = (),
    capture_to_world: np.ndarray | None = None,  # [3, 3] rotation, recorded for imported captures
) -> Subject:
    """Write a subject folder at ``path``; returns the written Subject (arrays as they were stored).

    The arrays are validated first (same rules as load_subject), then everything is written into a
    temporary sibling folder that is renamed onto ``path`` at the end: an error or interruption
    (including one raised by the ``images``/``masks`` iterables) leaves nothing at ``path`` and no
    temporary folder. Images and masks are consumed one at a time. An existing non-empty folder at
    ``path`` is replaced only with ``overwrite=True`` and only when it is a subject folder holding nothing
    else (``SUBJECT_FOLDER``); ``path`` may not be, hold or lie inside one of ``inputs`` (what the caller
    read: an import's capture).
    """
    where = "save_subject"
    target, inputs = Path(path), tuple(inputs)
    check_folder_target(target, overwrite, SUBJECT_FOLDER, inputs)
    if not isinstance(body, SkinnedMesh):
        raise FormatError(f"{where}: body: expected a SkinnedMesh, got {type(body).__name__}")

    sequence = np.asarray(list(sequence) if not isinstance(sequence, np.ndarray) else sequence).astype(np.str_)
    poses = np.asarray(poses)
    num_frames = len(poses) if poses.ndim else 0
    if frame_names is None:
        frame_names = [f"{i:06d}" for i in range(num_frames)]
    seq_order = list(dict.fromkeys(sequence.tolist()))
    bg = [as_real(c) for c in background]
    meta: dict[str, Any] = {
        "format": SUBJECT_FORMAT,
        "version": SUBJECT_VERSION,
        "body_model": body_model,
        "units": "m",
        "up_axis": "z",
        "width": int(width) if is_int(width) or isinstance(width, np.integer) else width,
        "height": int(height) if is_int(height) or isinstance(height, np.integer) else height,
        "num_frames": num_frames,
        "background": bg,
        "phenotype": {str(k): as_real(v) for k, v in dict(phenotype or {}).items()},
        "generator": plain_json(generator or {}, where, "generator"),
        "sequences": seq_order,
    }
    if capture_to_world is not None:
        meta["capture_to_world"] = np.asarray(capture_to_world, dtype=np.float64).tolist()
    check_subject_meta(meta, where)
    meta_text = json.dumps(meta, indent=2, allow_nan=False) + "\n"

    def as_str(a: Any) -> np.ndarray:
        a = np.asarray(a if isinstance(a, np.ndarray) else list(a))
        return a.astype(np.str_) if a.dtype.kind in "US" else a

    arrays = {
        "poses": poses, "trans": trans, "K": K, "viewmat": viewmat,
        "split": as_str(split), "sequence": sequence, "frame_names": as_str(frame_names),
        "poses_true": poses_true,
    }
    frames = check_frames(arrays, where, num_frames, body.skeleton.num_joints, seq_order)

    with atomic_folder(target, overwrite, SUBJECT_FOLDER, inputs) as tmp:
        write_npz(tmp / BODY_NPZ, body.to_arrays())
        write_npz(tmp / FRAMES_NPZ, frames)
        _write_frames(tmp, frames["frame_names"].tolist(), images, masks, int(width), int(height))
        write_synced(tmp / SUBJECT_JSON, meta_text.encode("utf-8"))
    return Subject(root=target, meta=meta, body=body, **frames)


def _write_frames(
    folder: Path, names: list[str], images: Iterable[np.ndarray], masks: Iterable[np.ndarray], W: int, H: int
) -> None:
    """Image i and mask i are pulled together, so tee'd iterables from one render pass buffer one frame."""
    N = len(names)
    streams = (("images", iter(images), IMAGES_DIR, (H, W, 3)), ("masks", iter(masks), MASKS_DIR, (H, W)))
    for _, _, sub, _ in streams:
        (folder / sub).mkdir()
    for i, name in enumerate(names):
        for kind, it, sub, want in streams:
            try:
                img = np.asarray(next(it))
            except StopIteration:
                raise FormatError(f"save_subject: {kind}: got {i} {kind} for {N} frames") from None
            label = f"save_subject: {kind}[{i}] (frame {name!r})"
            if kind == "masks" and img.ndim == 3 and img.shape[2] == 1:
                img = img[..., 0]
            if img.shape != want:
                raise FormatError(f"{label}: expected shape {list(want)} (height, width from the arguments), got {list(img.shape)}")
            try:
                data = encode_png(img, name=label)
            except ValueError as err:
                raise FormatError(str(err)) from None
            write_synced(folder / sub / f"{name}.png", data)
    for kind, it, _, _ in streams:
        if next(it, None) is not None:
            raise FormatError(f"save_subject: {kind}: got more {kind} than the {N} frames")
