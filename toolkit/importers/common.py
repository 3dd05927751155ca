"""What every importer shares: the output check made before anything is read, strict readers (JSON through
``formats.common.read_json``, pickles behind a flag, .npy/.npz without pickle, images, masks, COLMAP text),
SMPL-X parameter checks, and the one writer that turns checked frames into a subject folder.

Every problem is a one-line ``FormatError`` naming the file and the field. Everything is read and
checked before the first byte is written, and the subject is written by ``save_subject`` (a temporary
sibling folder renamed into place), so bad input leaves nothing behind.
"""

from __future__ import annotations

import itertools
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np

from trioman.runtime.formats import FormatError, Subject, save_subject
from trioman.runtime.formats.common import read_json as _read_json, require_file
from trioman.runtime.formats.subject import SUBJECT_FOLDER
from trioman.runtime.image_io import read_png
from trioman.runtime.outputs import check_folder_target
from trioman.runtime.rotations import axis_angle_to_matrix, matrix_to_axis_angle, quat_to_matrix
from trioman.toolkit.body.smplx_model import (
    SMPLXBody, Y_UP_TO_Z_UP, full_pose, load_model_arrays, model_file, viewmat_to_z_up,
)
from trioman.toolkit.importers.options import UP_SOURCES

# SMPL-X parameters of one frame: name -> shape (axis-angle in SMPL-X's frame, hands relative to their mean).
PARAM_SHAPES = {"root": (3,), "body": (21, 3), "jaw": (3,), "leye": (3,), "reye": (3,), "lhand": (15, 3),
                "rhand": (15, 3), "transl": (3,)}
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")


@dataclass
class FrameRecord:
    """One frame as read from a capture: files, SMPL-X parameters and the camera (world -> camera)."""

    name: str  # the subject's frame name (file stem)
    split: str  # "train" | "test"
    sequence: str
    image: Path
    mask: Callable[[], np.ndarray]  # -> float32 [H, W] in [0, 1], read when the frame is written
    params: dict[str, np.ndarray]  # PARAM_SHAPES
    R: np.ndarray  # [3, 3] world -> camera rotation of the capture's world
    t: np.ndarray  # [3]
    focal: np.ndarray  # [2] pixels
    princpt: np.ndarray  # [2] pixels
    in_camera: bool = False  # params given in the camera frame (ExAvatar's NeuMan, Custom, fitters)
    mask_file: Path | None = None  # the file ``mask`` reads (named when its size differs)


# --------------------------------------------------------------------------------------------------
# readers


def read_json(path: Path) -> Any:
    """A JSON file through the one reader (``formats.common.read_json``: NaN and Infinity refused). A file holding
    NaN or Infinity, as Python's ``json.dump`` writes a non-finite float, is refused naming the field that holds it
    (a top-level key, or the item of a top-level list)."""
    try:
        return _read_json(path)
    except FormatError as err:
        if "is not valid JSON" in str(err):
            where = _non_finite_field(path)
            if where is not None:
                raise FormatError(f"{path}: {where}: NaN or Infinity, which JSON does not allow (a non-finite "
                                  f"value)") from None
        raise


def _non_finite_field(path: Path) -> str | None:
    """The first top-level key (or list item) of a JSON file whose value holds NaN or Infinity; None if none is found."""
    import json
    import math

    def bad(value: Any) -> bool:
        if isinstance(value, float):
            return not math.isfinite(value)
        if isinstance(value, dict):
            return any(bad(v) for v in value.values())
        return isinstance(value, list) and any(bad(v) for v in value)

    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (ValueError, UnicodeDecodeError, RecursionError, OSError):
        return None
    items = data.items() if isinstance(data, dict) else enumerate(data) if isinstance(data, list) else []
    for key, value in items:
        if bad(value):
            return str(key) if isinstance(data, dict) else f"item {key}"
    return None


def focal_array(where: Path, field: str, value: Any) -> np.ndarray:
    """A focal length (fx, fy) in pixels: two finite numbers > 0."""
    focal = array(where, field, value, (2,))
    if not np.all(focal > 0):
        raise FormatError(f"{where}: {field}: focal length must be > 0, got {focal.tolist()}")
    return focal


def read_pickle(path: Path, allow_pickle: bool) -> Any:
    """A pickled file (X-Humans' original fits), only with ``allow_pickle``: unpickling runs code."""
    require_file(path)
    if not allow_pickle:
        raise FormatError(f"{path}: a pickled file; reading it runs code from the file, so it is read only with "
                          f"`allow_pickle` (give it for files you trust)")
    import pickle

    try:
        with open(path, "rb") as f:
            return pickle.load(f, encoding="latin1")
    except Exception as err:  # any unpickling failure means the file is unusable
        raise FormatError(f"{path}: unreadable pickle ({type(err).__name__}: {err})") from None


def check_target(out: str | Path, overwrite: bool, inputs: list[Path]) -> None:
    """Before anything is read: ``out`` may take a subject folder (``outputs.check_folder_target``: empty, absent,
    or with ``overwrite`` a subject folder holding nothing else) and is not, does not hold and does not lie inside
    one of ``inputs`` (the capture, the frames, fits and masks folders)."""
    check_folder_target(Path(out), overwrite, SUBJECT_FOLDER, inputs=inputs)


def read_npy(path: Path) -> np.ndarray:
    """One array of a .npy file, without pickle."""
    require_file(path)
    try:
        return np.load(path, allow_pickle=False)
    except Exception as err:  # numpy raises several types; all mean unreadable
        raise FormatError(f"{path}: unreadable .npy without pickle ({type(err).__name__}: {err})") from None


def pelvis_per_beta(model_dir: str | Path, gender: str, num_betas: int) -> np.ndarray:
    """[3, num_betas]: how the rest pelvis (SMPL-X frame) moves per shape coefficient (it is linear in the betas).
    A fit made for betas b keeps its pelvis where b put it under the betas m when its transl gains
    ``pelvis_per_beta @ (b - m)`` (the posed pelvis is the rest pelvis + transl, whatever the pose)."""
    model = load_model_arrays(model_file(model_dir, gender))
    return np.einsum("v,vck->ck", model["J_regressor"][0], model["shapedirs"][:, :, :num_betas])


def read_npz(path: Path) -> dict[str, np.ndarray]:
    """All arrays of an .npz, without pickle."""
    require_file(path)
    try:
        with np.load(path, allow_pickle=False) as archive:
            return {k: archive[k] for k in archive.files}
    except Exception as err:  # numpy raises several types; all mean unreadable
        raise FormatError(f"{path}: unreadable .npz without pickle ({type(err).__name__}: {err})") from None


def array(where: Path, field: str, value: Any, shape: tuple[int, ...]) -> np.ndarray:
    """``value`` as a finite float64 array of ``shape`` (any layout with the same number of values)."""
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise FormatError(f"{where}: {field}: expected numbers, got {type(value).__name__}") from None
    if a.size != int(np.prod(shape)):
        raise FormatError(f"{where}: {field}: expected shape {list(shape)} ({int(np.prod(shape))} values), "
                          f"got {list(a.shape)}")
    bad = int((~np.isfinite(a)).sum())
    if bad:
        raise FormatError(f"{where}: {field}: {bad} non-finite value(s) (NaN/Inf)")
    return a.reshape(shape)


def smplx_params(where: Path, source: dict, keys: dict[str, str], defaults: tuple[str, ...] = ()) -> dict[str, np.ndarray]:
    """SMPL-X parameters of one frame from a mapping. keys: our name -> the file's key; names in ``defaults``
    are zero when the file lacks them."""
    if not isinstance(source, dict):
        raise FormatError(f"{where}: expected an object of SMPL-X parameters, got {type(source).__name__}")
    out = {}
    for name, key in keys.items():
        if key not in source:
            if name in defaults:
                out[name] = np.zeros(PARAM_SHAPES[name])
                continue
            raise FormatError(f"{where}: {key}: missing field")
        out[name] = array(where, key, source[key], PARAM_SHAPES[name])
    return out


def read_image(path: Path) -> np.ndarray:
    """float32 RGB [H, W, 3] in [0, 1] (PNG or JPEG)."""
    try:
        return read_png(path, mode="rgb")
    except FileNotFoundError:
        raise FormatError(f"{path}: missing file") from None
    except ValueError as err:
        raise FormatError(str(err)) from None


def read_gray(path: Path) -> np.ndarray:
    """float32 [H, W] as stored (8/16-bit scaled to [0, 1], float TIFF as is)."""
    try:
        img = read_png(path)
    except FileNotFoundError:
        raise FormatError(f"{path}: missing file") from None
    except ValueError as err:
        raise FormatError(str(err)) from None
    return img if img.ndim == 2 else img[..., 0]


def image_size(path: Path) -> tuple[int, int]:
    """(width, height) of an image file."""
    img = read_image(path)
    return img.shape[1], img.shape[0]


def frame_index(path: Path) -> int | None:
    """The frame number in a file stem (its last run of digits), None without digits."""
    digits = re.findall(r"\d+", path.stem)
    return int(digits[-1]) if digits else None


def files_by_index(folder: Path, suffixes: tuple[str, ...], what: str) -> dict[int, Path]:
    """Files of a folder with one of ``suffixes`` by frame number (the last run of digits in the stem), so
    ``12.json`` and ``00012.json`` both index frame 12. A folder without such files, or two files with the
    same number, -> FormatError."""
    if not folder.is_dir():
        raise FormatError(f"{folder}: missing folder ({what})")
    found: dict[int, Path] = {}
    for p in sorted(folder.iterdir()):
        idx = frame_index(p)
        if p.suffix.lower() not in suffixes or idx is None:
            continue
        if idx in found:
            raise FormatError(f"{folder}: {found[idx].name} and {p.name} are both frame {idx} ({what})")
        found[idx] = p
    if not found:
        raise FormatError(f"{folder}: no {what} found")
    return found


def images_by_index(folder: Path, what: str) -> dict[int, Path]:
    """Image files of a folder by frame number; a folder without images -> FormatError."""
    return files_by_index(folder, IMAGE_SUFFIXES + (".tiff", ".tif"), what)


def read_split_list(path: Path) -> list[int]:
    """A split list (``00012.png`` or ``12`` per line) -> frame numbers; a frame listed twice -> FormatError."""
    require_file(path)
    first_line: dict[int, int] = {}
    for n, line in enumerate(path.read_text().splitlines(), 1):
        if line.strip():
            idx = frame_index(Path(line.strip()))
            if idx is None:
                raise FormatError(f"{path}: line {n}: {line.strip()!r} names no frame number")
            if idx in first_line:
                raise FormatError(f"{path}: line {n}: frame {idx} is listed twice (first on line {first_line[idx]})")
            first_line[idx] = n
    return list(first_line)


def read_colmap(sparse: Path) -> tuple[np.ndarray, np.ndarray, dict[int, tuple[np.ndarray, np.ndarray]]]:
    """COLMAP text model: one shared PINHOLE/SIMPLE_PINHOLE camera -> focal [2], princpt [2], and per image
    (by the frame number in its name) world -> camera (R [3, 3], t [3])."""
    cams_path, images_path = sparse / "cameras.txt", sparse / "images.txt"
    cameras = [ln.split() for ln in _lines(cams_path)]
    if len(cameras) != 1:
        raise FormatError(f"{cams_path}: expected one shared camera, got {len(cameras)}")
    tok = cameras[0]
    try:
        params = [float(v) for v in tok[4:]]
    except ValueError:
        raise FormatError(f"{cams_path}: camera parameters: not numbers: {tok[4:]}") from None
    if len(tok) < 4 or tok[1] not in ("PINHOLE", "SIMPLE_PINHOLE") or len(params) != (4 if tok[1] == "PINHOLE" else 3):
        raise FormatError(f"{cams_path}: camera: expected 'ID PINHOLE W H fx fy cx cy' (or SIMPLE_PINHOLE W H f cx cy), "
                          f"got {' '.join(tok)!r}")
    names = "fx fy cx cy" if tok[1] == "PINHOLE" else "f cx cy"
    params = array(cams_path, f"camera parameters: {names}", params, (len(params),)).tolist()
    focal = focal_array(cams_path, "camera parameters", params[:2] if tok[1] == "PINHOLE" else params[:1] * 2)
    princpt = np.array(params[-2:])
    poses = {}
    for ln in _lines(images_path):
        tok = ln.split()
        if len(tok) != 10 or not tok[9].lower().endswith(IMAGE_SUFFIXES):
            continue  # the 2D-point line after each image line
        idx = frame_index(Path(tok[9]))
        q = array(images_path, f"{tok[9]}: QW QX QY QZ", [_float(images_path, v) for v in tok[1:5]], (4,))
        t = array(images_path, f"{tok[9]}: TX TY TZ", [_float(images_path, v) for v in tok[5:8]], (3,))
        if idx is None or np.linalg.norm(q) < 1e-8:
            raise FormatError(f"{images_path}: {tok[9]}: no frame number in the name, or a zero quaternion")
        poses[idx] = (quat_to_matrix(q), t)
    if not poses:
        raise FormatError(f"{images_path}: no image lines ('ID QW QX QY QZ TX TY TZ CAMERA_ID NAME')")
    return focal, princpt, poses


def _lines(path: Path) -> list[str]:
    require_file(path)
    return [ln for ln in path.read_text().splitlines() if ln.strip() and not ln.lstrip().startswith("#")]


def _float(path: Path, v: str) -> float:
    try:
        return float(v)
    except ValueError:
        raise FormatError(f"{path}: {v!r} is not a number") from None


# --------------------------------------------------------------------------------------------------
# the subject


def _to_world(records: list[FrameRecord], root_joint: np.ndarray) -> None:
    """Parameters given in the camera frame -> the capture's world, as ExAvatar does (x_w = R^T (x_c - t)):
    the root rotation becomes R^T R_root and the translation R^T (j0 + transl - t) - j0 (j0: rest pelvis)."""
    for r in records:
        if not r.in_camera:
            continue
        R_root = r.R.T @ axis_angle_to_matrix(r.params["root"])
        r.params["root"] = matrix_to_axis_angle(R_root)
        r.params["transl"] = r.R.T @ (root_joint + r.params["transl"] - r.t) - root_joint
        r.in_camera = False


def _rotation_onto(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation taking unit vector a onto unit vector b (a half turn about an axis normal to a when
    they are opposite)."""
    axis = np.cross(a, b)
    s, c = float(np.linalg.norm(axis)), float(a @ b)
    if s < 1e-12:
        if c > 0:
            return np.eye(3)
        normal = np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0])
        return axis_angle_to_matrix(np.pi * normal / np.linalg.norm(normal))
    return axis_angle_to_matrix(axis / s * np.arctan2(s, c))


def body_up(records: list[FrameRecord], rest_joints: np.ndarray) -> np.ndarray:
    """The capture world's up from the body, as ml-neuman finds it (``utils/utils.py``,
    ``smpl_verts_to_center_and_up``: the spine of the rest-posed body placed in the world): the rest spine
    (pelvis -> spine3, SMPL-X frame) turned by each frame's root rotation, averaged over the frames. [3], unit."""
    spine = rest_joints[9] - rest_joints[0]
    spine = spine / np.linalg.norm(spine)
    dirs = np.stack([axis_angle_to_matrix(r.params["root"]) @ spine for r in records])
    mean = dirs.mean(0)
    if np.linalg.norm(mean) < 0.5:
        raise FormatError("up body: the body's spine points in no common direction over the frames (mean length "
                          f"{np.linalg.norm(mean):.2f}); give `up` cameras or `up` none")
    return mean / np.linalg.norm(mean)


def cameras_up(records: list[FrameRecord]) -> np.ndarray:
    """The capture world's up from the cameras: the mean of each camera's up (its -y axis in the world). [3], unit."""
    mean = -np.stack([r.R[1] for r in records]).mean(0)
    if np.linalg.norm(mean) < 0.5:
        raise FormatError("up cameras: the cameras' up vectors point in no common direction (mean length "
                          f"{np.linalg.norm(mean):.2f}); give `up` body or `up` none")
    return mean / np.linalg.norm(mean)


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip(a @ b / (np.linalg.norm(a) * np.linalg.norm(b)), -1.0, 1.0))))


def _rotate_world(records: list[FrameRecord], U: np.ndarray, root_joint: np.ndarray) -> None:
    """Turn the capture's world by U (x -> U x) about its origin: root rotations U R_root, translations
    U (j0 + transl) - j0, cameras R U^T (t unchanged), so every camera sees the same pixels."""
    for r in records:
        r.params["root"] = matrix_to_axis_angle(U @ axis_angle_to_matrix(r.params["root"]))
        r.params["transl"] = U @ (root_joint + r.params["transl"]) - root_joint
        r.R = r.R @ U.T


def upright(records: list[FrameRecord], rest_joints: np.ndarray, up: str,
            say: Callable[[str], None]) -> tuple[np.ndarray, dict[str, Any]]:
    """Turn the capture's world (params in the world already) so its up is SMPL-X's +y, which becomes TrioMan's
    +z. up: "body" (the rest spine turned by the roots), "cameras" (their mean up) or "none" (the capture's
    world kept: its +y is taken as up). -> (U [3, 3], what to record in the generator)."""
    if up not in UP_SOURCES:
        raise ValueError(f"up: expected one of {list(UP_SOURCES)}, got {up!r}")
    y = np.array([0.0, 1.0, 0.0])
    body, cams = body_up(records, rest_joints), cameras_up(records)
    chosen = {"body": body, "cameras": cams, "none": y}[up]
    U = _rotation_onto(chosen, y)
    _rotate_world(records, U, rest_joints[0])
    info = {"source": up, "turn_deg": round(_angle_deg(chosen, y), 3),
            "body_to_cameras_deg": round(_angle_deg(body, cams), 3)}
    say(f"import: world up from {'the capture (+y kept)' if up == 'none' else 'the ' + up}: the capture's world is turned "
        f"by {info['turn_deg']:.1f} deg so the person stands along +z; the body's and the cameras' up differ by "
        f"{info['body_to_cameras_deg']:.1f} deg")
    return U, info


def write_subject(out: Path, body: SMPLXBody, records: list[FrameRecord], generator: dict[str, Any],
                  overwrite: bool = False, up: str = "body", say: Callable[[str], None] = print,
                  inputs: tuple[Path, ...] = ()) -> Subject:
    """Check the frames against each other and write the subject (images premultiplied by their mask, on black).

    Poses are SMPL-X full poses and everything is moved to TrioMan's z-up world (docs/formats.md), turned so
    the person stands along +z (``upright``); subject.json's ``capture_to_world`` records the rotation from the
    capture's world (cameras' and fits' frame) to the subject's. ``inputs``: the folders read, which ``out`` may
    not be, hold or lie inside."""
    if not records:
        raise FormatError(f"{out}: no frames to import")
    splits = {r.split for r in records}
    if "train" not in splits:
        raise FormatError(f"{out}: no training frames (check the split lists)")
    if up not in UP_SOURCES:
        raise ValueError(f"up: expected one of {list(UP_SOURCES)}, got {up!r}")
    W, H = image_size(records[0].image)
    rest_joints = body.rest_joints.double().numpy() @ Y_UP_TO_Z_UP  # back to SMPL-X's frame
    root_joint = rest_joints[0]
    _to_world(records, root_joint)
    U, up_info = upright(records, rest_joints, up, say)
    generator = {**generator, "up": up_info}
    p = {k: np.stack([r.params[k] for r in records]) for k in PARAM_SHAPES}
    pose = full_pose(body.hand_mean.double().numpy(), p["root"], p["body"], p["jaw"], p["leye"], p["reye"],
                     p["lhand"], p["rhand"])
    trans = p["transl"] @ Y_UP_TO_Z_UP.T
    view = np.tile(np.eye(4), (len(records), 1, 1))
    view[:, :3, :3] = np.stack([r.R for r in records])
    view[:, :3, 3] = np.stack([r.t for r in records])
    K = np.tile(np.eye(3), (len(records), 1, 1))
    K[:, 0, 0], K[:, 1, 1] = [np.array([r.focal[i] for r in records]) for i in (0, 1)]
    K[:, 0, 2], K[:, 1, 2] = [np.array([r.princpt[i] for r in records]) for i in (0, 1)]

    def frames() -> Iterator[tuple[np.ndarray, np.ndarray]]:
        for r in records:
            img, mask = read_image(r.image), r.mask()
            if img.shape[:2] != (H, W):
                raise FormatError(f"{r.image}: size {img.shape[1]}x{img.shape[0]} (W x H) differs from the first "
                                  f"frame's image {W}x{H} ({records[0].image.name})")
            if mask.shape != (H, W):
                raise FormatError(f"{r.mask_file or 'the mask'}: mask of frame {r.name!r}: size {mask.shape[1]}x"
                                  f"{mask.shape[0]} (W x H) differs from the first frame's image {W}x{H}")
            yield img * mask[..., None], mask

    a, b = itertools.tee(frames())
    return save_subject(
        out, body=body.to_skinned_mesh(), poses=pose.astype(np.float32), trans=trans.astype(np.float32),
        K=K.astype(np.float32), viewmat=viewmat_to_z_up(view).astype(np.float32), split=[r.split for r in records],
        sequence=[r.sequence for r in records], images=(f[0] for f in a), masks=(f[1] for f in b), width=W, height=H,
        body_model="smplx", background=(0.0, 0.0, 0.0), generator=generator,
        frame_names=[r.name for r in records], overwrite=overwrite, inputs=inputs,
        capture_to_world=Y_UP_TO_Z_UP @ U)
