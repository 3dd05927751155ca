"""The avatar format (versions 1 and 2) is a folder; docs/formats.md documents it in full.

    avatar.json            metadata: format, version, body model, counts, options, source, files + sha256
    gaussians.npz          baked pose-independent attributes (pre-activation) + sparse skinning
                           (+ version 2: the sparse map carrying pose deltas from M points to the Gaussians)
    skeleton.npz           joint_names, parents, joints (rest)
    pose_dependent.onnx    pose [J,3] -> d_offset [M,3], d_log_scale [M,S], d_rgb [M,3] (optional;
                           M = N in version 1, avatar.json pose_points in version 2)
    canonical.ply          the avatar at the rest pose, standard 3DGS .ply (for splat viewers)
    posed_<name>.ply       optional extra posed .ply files

``load_avatar`` validates everything (and every file's sha256) and raises ``FormatError`` naming the
file and the field; ``save_avatar`` writes a temporary sibling folder and renames it into place.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from trioman.runtime.avatar import SCALE_CLAMP, Avatar
from trioman.runtime.formats.common import (
    FormatError,
    check_header,
    format_error,
    is_int,
    load_json,
    load_npz,
    plain_json,
    require_file,
    write_npz,
)
from trioman.runtime.outputs import FolderKind, atomic_folder, check_folder_target, known_kind, write_synced
from trioman.runtime.skeleton import Skeleton

AVATAR_FORMAT = "trioman-avatar"
AVATAR_VERSION = 2  # version 2 adds pose_points and the arrays that carry the pose deltas
AVATAR_VERSIONS = (1, 2)  # read; save_avatar writes version 1 for an avatar without pose_points

AVATAR_JSON = "avatar.json"
GAUSSIANS_NPZ = "gaussians.npz"
SKELETON_NPZ = "skeleton.npz"
POSE_ONNX = "pose_dependent.onnx"
CANONICAL_PLY = "canonical.ply"
ONNX_INPUT = "pose"
ONNX_OUTPUTS = ("d_offset", "d_log_scale", "d_rgb")
WEIGHT_SUM_TOL = 1e-4

_FLOAT_FIELDS = ("positions", "log_scales", "rgb_logits", "opacities", "local_quats", "skin_weights", "pose_weights")
_INDEX_FIELDS = ("skin_indices", "pose_indices")
_POSE_CARRY = ("pose_indices", "pose_weights")
# What --overwrite may replace (outputs.check_folder_target): a folder of exactly these files.
AVATAR_FOLDER = known_kind(FolderKind("avatar", AVATAR_JSON, files=(AVATAR_JSON, GAUSSIANS_NPZ, SKELETON_NPZ, POSE_ONNX, CANONICAL_PLY,
                                                     "posed_*.ply"), format=AVATAR_FORMAT))
_EXTRA_PLY = re.compile(r"posed_[A-Za-z0-9_.\-]{1,100}\.ply")  # fullmatch


def sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


# --------------------------------------------------------------------------------------------------
# validation (shared by load and save; ``where`` is the file path or "save_avatar")


def _check_meta(meta: Any, where: Any) -> dict[str, Any]:
    version = meta.get("version") if isinstance(meta, dict) else None
    get = check_header(meta, where, AVATAR_FORMAT, version if version in AVATAR_VERSIONS else AVATAR_VERSION, "avatar")
    n = get("num_gaussians")
    if not is_int(n) or n <= 0:
        raise format_error(where, "num_gaussians", f"expected a positive integer, got {n!r}")
    for field in ("anisotropic", "pose_dependent"):
        if not isinstance(get(field), bool):
            raise format_error(where, field, f"expected true or false, got {meta[field]!r}")
    _check_pose_points(meta, where)
    clamp = get("scale_clamp")
    if clamp != list(SCALE_CLAMP):
        raise format_error(where, "scale_clamp", f"expected {list(SCALE_CLAMP)} (log-scale clamp), got {clamp!r}")
    joints = get("pose_joints")
    if not (isinstance(joints, list) and all(isinstance(j, str) and j for j in joints)):
        raise format_error(where, "pose_joints", f"expected a list of joint names, got {joints!r}")
    if meta["pose_dependent"] and not joints:
        raise format_error(where, "pose_joints", "empty, but pose_dependent is true")
    if not isinstance(get("trioman_version"), str):
        raise format_error(where, "trioman_version", f"expected a string, got {meta['trioman_version']!r}")
    if not isinstance(get("source"), dict):
        raise format_error(where, "source", f"expected an object, got {type(meta['source']).__name__}")
    files = get("files")
    if not isinstance(files, dict):
        raise format_error(where, "files", f"expected an object of file name -> {{sha256, bytes}}, got {type(files).__name__}")
    required = [GAUSSIANS_NPZ, SKELETON_NPZ, CANONICAL_PLY] + ([POSE_ONNX] if meta["pose_dependent"] else [])
    for name in required:
        if name not in files:
            raise format_error(where, f"files.{name}", "missing entry")
    allowed = set(required)
    for name, entry in files.items():
        if name not in allowed and not _EXTRA_PLY.fullmatch(name):
            raise format_error(where, f"files.{name}", f"unexpected file name (allowed: {sorted(allowed)} and posed_<name>.ply)")
        if not (isinstance(entry, dict) and isinstance(entry.get("sha256"), str) and re.fullmatch(r"[0-9a-f]{64}", entry["sha256"])
                and is_int(entry.get("bytes")) and entry["bytes"] >= 0):
            raise format_error(where, f"files.{name}", f"expected {{'sha256': 64 hex digits, 'bytes': size}}, got {entry!r}")
    return meta


def _check_pose_points(meta: dict[str, Any], where: Any) -> None:
    """Version 2 requires pose_points (M, the rows of the graph's outputs) and pose-dependent terms; version 1 has none."""
    if meta["version"] == 1:
        if "pose_points" in meta:
            raise format_error(where, "pose_points", "not a version 1 field (version 2 adds it)")
        return
    m = meta.get("pose_points")
    if not is_int(m) or m <= 0:
        raise format_error(where, "pose_points", f"expected a positive integer (the pose-dependent graph's rows), got {m!r}")
    if not meta["pose_dependent"]:
        raise format_error(where, "pose_points", "given, but pose_dependent is false (a version 2 avatar has pose-dependent terms)")


def _check_skeleton(arrays: Mapping[str, np.ndarray], where: Any) -> Skeleton:
    for key in ("joint_names", "parents", "joints"):
        if key not in arrays:
            raise format_error(where, key, f"missing array (has: {sorted(arrays)})")
    names = np.asarray(arrays["joint_names"])
    if names.ndim != 1 or names.dtype.kind != "U":
        raise format_error(where, "joint_names", f"expected a 1-D unicode array, got dtype {names.dtype} shape {list(names.shape)}")
    try:
        return Skeleton(tuple(names.tolist()), np.asarray(arrays["parents"]), np.asarray(arrays["joints"]))
    except ValueError as err:
        raise FormatError(f"{where}: {err}") from None


def _check_gaussians(arrays: Mapping[str, np.ndarray], where: Any, N: int, J: int, anisotropic: bool,
                     M: int | None = None) -> dict[str, np.ndarray]:
    """The gaussians.npz arrays checked (M: avatar.json pose_points, None in version 1) -> float32 / int32 arrays."""
    S = 3 if anisotropic else 1
    shapes: dict[str, tuple] = {"positions": (N, 3), "log_scales": (N, S), "rgb_logits": (N, 3), "opacities": (N,),
                                "skin_indices": (N, None), "skin_weights": (N, None)}
    if anisotropic:
        shapes["local_quats"] = (N, 4)
    elif "local_quats" in arrays:
        raise format_error(where, "local_quats", "present, but avatar.json says the avatar is isotropic (anisotropic: false)")
    if M is not None:
        shapes |= {key: (N, None) for key in _POSE_CARRY}
    for key in _POSE_CARRY:
        if M is None and key in arrays:
            raise format_error(where, key, "present, but avatar.json has no pose_points (a version 2 field)")
    out: dict[str, np.ndarray] = {}
    for key, want in shapes.items():
        if key not in arrays:
            raise format_error(where, key, f"missing array (has: {sorted(arrays)})")
        a = np.asarray(arrays[key])
        kinds = "iu" if key in _INDEX_FIELDS else "fiu"
        if a.dtype.kind not in kinds:
            raise format_error(where, key, f"expected {'integers' if key in _INDEX_FIELDS else 'floats'}, got dtype {a.dtype}")
        if a.ndim != len(want) or any(w is not None and s != w for s, w in zip(a.shape, want)):
            if a.ndim >= 1 and a.shape[0] != N and a.ndim == len(want):
                raise format_error(where, key, f"{a.shape[0]} Gaussians, but avatar.json num_gaussians is {N}")
            shown = "[" + ", ".join("K" if w is None else str(w) for w in want) + "]"
            raise format_error(where, key, f"expected shape {shown}, got {list(a.shape)}")
        if key in _FLOAT_FIELDS:
            a = a.astype(np.float32)
            bad = ~np.isfinite(a)
            if bad.any():
                first = int(np.flatnonzero(bad.reshape(N, -1).any(axis=1))[0])
                raise format_error(where, key, f"{int(bad.sum())} non-finite value(s) (NaN/Inf), first at Gaussian {first}")
        out[key] = a
    _check_rows(out, where, "skin", J, f"joint indices must lie in [0, {J}) (skeleton.npz has {J} joints)")
    if M is not None:
        _check_rows(out, where, "pose", M, f"pose point indices must lie in [0, {M}) (avatar.json pose_points)")
    o = out["opacities"]
    if np.any((o < 0) | (o > 1)):
        raise format_error(where, "opacities", f"values must lie in [0, 1], got [{o.min()}, {o.max()}]")
    return out


def _check_rows(out: dict[str, np.ndarray], where: Any, prefix: str, cols: int, bound: str) -> None:
    """``<prefix>_indices`` / ``<prefix>_weights`` [N, K] as a sparse map of rows (in place: indices -> int32):
    the same shape, K >= 1, indices in [0, cols) (``bound`` says so), weights >= 0 summing to 1 per row."""
    ikey, wkey = f"{prefix}_indices", f"{prefix}_weights"
    idx, w = out[ikey], out[wkey]
    if idx.shape != w.shape:
        raise format_error(where, wkey, f"shape {list(w.shape)} differs from {ikey} {list(idx.shape)}")
    if idx.shape[1] == 0:
        raise format_error(where, ikey, "no influences (K = 0)")
    if idx.min() < 0 or idx.max() >= cols:
        raise format_error(where, ikey, f"{bound}, got [{idx.min()}, {idx.max()}]")
    out[ikey] = idx.astype(np.int32)
    if np.any(w < 0):
        raise format_error(where, wkey, f"{int((w < 0).sum())} negative weight(s)")
    sums = w.sum(axis=1, dtype=np.float64)
    if np.any(np.abs(sums - 1.0) > WEIGHT_SUM_TOL):
        worst = int(np.argmax(np.abs(sums - 1.0)))
        raise format_error(where, wkey, f"rows must sum to 1, Gaussian {worst} sums to {sums[worst]:.6f}")


def _open_onnx(model: Path | bytes, where: Any, J: int, N: int, S: int) -> Any:
    """An onnxruntime session (CPU) of the pose-dependent graph (N output rows: the Gaussians, or avatar.json
    pose_points), its inputs/outputs checked and run once."""
    import onnxruntime as ort

    opts = ort.SessionOptions()
    opts.log_severity_level = 3
    try:
        src = str(model) if isinstance(model, Path) else model
        session = ort.InferenceSession(src, sess_options=opts, providers=["CPUExecutionProvider"])
    except Exception as err:
        raise format_error(where, None, f"not a loadable ONNX model ({type(err).__name__}: {str(err).splitlines()[0][:300]})") from None
    inputs = session.get_inputs()
    if [i.name for i in inputs] != [ONNX_INPUT]:
        raise format_error(where, "inputs", f"expected one input {ONNX_INPUT!r}, got {[i.name for i in inputs]}")
    if inputs[0].type != "tensor(float)" or list(inputs[0].shape) != [J, 3]:
        raise format_error(where, ONNX_INPUT, f"expected float32 [{J}, 3], got {inputs[0].type} {inputs[0].shape}")
    names = [o.name for o in session.get_outputs()]
    if sorted(names) != sorted(ONNX_OUTPUTS):
        raise format_error(where, "outputs", f"expected {list(ONNX_OUTPUTS)}, got {names}")
    try:
        outs = session.run(list(ONNX_OUTPUTS), {ONNX_INPUT: np.zeros((J, 3), np.float32)})
    except Exception as err:
        raise format_error(where, None, f"the graph fails to run ({type(err).__name__}: {str(err).splitlines()[0][:300]})") from None
    for name, out, cols in zip(ONNX_OUTPUTS, outs, (3, S, 3)):
        if out.shape != (N, cols) or out.dtype != np.float32:
            raise format_error(where, name, f"expected float32 [{N}, {cols}], got {out.dtype} {list(out.shape)}")
        if not np.all(np.isfinite(out)):
            raise format_error(where, name, "non-finite value(s) (NaN/Inf) at the zero pose")
    return session


# --------------------------------------------------------------------------------------------------
# load


def load_avatar(path: str | os.PathLike) -> Avatar:
    """Load and validate an avatar folder (see docs/formats.md). Raises FormatError."""
    root = Path(path)
    if not root.exists():
        raise FormatError(f"{root}: avatar folder not found")
    if not root.is_dir():
        raise FormatError(f"{root}: not a folder (an avatar is a folder with {AVATAR_JSON}, {GAUSSIANS_NPZ}, "
                          f"{SKELETON_NPZ}, {CANONICAL_PLY} and optionally {POSE_ONNX})")
    meta_path = root / AVATAR_JSON
    require_file(meta_path, "missing file (is this a TrioMan avatar folder?)")
    meta = _check_meta(load_json(meta_path), meta_path)
    for name, entry in meta["files"].items():
        f = root / name
        require_file(f, f"missing file (listed in {AVATAR_JSON})")
        size = f.stat().st_size
        if size != entry["bytes"]:
            raise FormatError(f"{f}: {size} bytes, but {AVATAR_JSON} lists {entry['bytes']} (truncated or modified file)")
        digest = sha256_file(f)
        if digest != entry["sha256"]:
            raise FormatError(f"{f}: sha256 {digest[:12]}... does not match {AVATAR_JSON} ({entry['sha256'][:12]}...): corrupt or modified file")
    if not meta["pose_dependent"] and (root / POSE_ONNX).exists():
        raise FormatError(f"{root / POSE_ONNX}: present, but {AVATAR_JSON} pose_dependent is false")

    sk_path = root / SKELETON_NPZ
    skeleton = _check_skeleton(load_npz(sk_path), sk_path)
    _check_pose_joints(meta["pose_joints"], skeleton, meta_path)
    g_path = root / GAUSSIANS_NPZ
    M = meta.get("pose_points")
    arrays = _check_gaussians(load_npz(g_path), g_path, meta["num_gaussians"], skeleton.num_joints, meta["anisotropic"], M)
    session = None
    if meta["pose_dependent"]:
        session = _open_onnx(root / POSE_ONNX, root / POSE_ONNX, skeleton.num_joints, M or meta["num_gaussians"],
                             3 if meta["anisotropic"] else 1)
    return Avatar(skeleton, arrays, meta, session, root)


def _check_pose_joints(names: Sequence[str], skeleton: Skeleton, where: Any) -> None:
    unknown = [n for n in names if n not in skeleton.joint_names]
    if unknown:
        raise format_error(where, "pose_joints", f"unknown joint name(s) {unknown[:5]} (the skeleton has {skeleton.num_joints} joints)")
    if len(set(names)) != len(names):
        raise format_error(where, "pose_joints", "duplicate joint names")


# --------------------------------------------------------------------------------------------------
# save


def save_avatar(
    path: str | os.PathLike,
    *,
    skeleton: Skeleton,
    gaussians: Mapping[str, np.ndarray],  # the gaussians.npz arrays (see docs/formats.md)
    body_model: str,
    pose_joints: Sequence[str] = (),
    pose_dependent_onnx: bytes | None = None,  # serialized ONNX model, None = no pose-dependent terms
    pose_points: int | None = None,  # M, the graph's output rows, with gaussians' pose_indices/pose_weights (version 2)
    source: Mapping[str, Any] | None = None,
    posed: Mapping[str, tuple[np.ndarray, np.ndarray]] | None = None,  # name -> (pose [J,3], trans [3]): posed_<name>.ply
    overwrite: bool = False,
    inputs: Sequence[str | os.PathLike | None] = (),
) -> Avatar:
    """Validate and write an avatar folder at ``path``; returns it loaded back (``load_avatar``).

    The folder is version 2 with ``pose_points``, else version 1.
    Everything is written into a temporary sibling folder renamed onto ``path`` at the end: an error
    leaves nothing at ``path``. An existing non-empty folder is replaced only with ``overwrite=True`` and only
    when it is an avatar folder holding nothing else (``AVATAR_FOLDER``); ``path`` may not be, hold or lie
    inside one of ``inputs`` (what the caller read: the run, its checkpoint and subject).
    canonical.ply holds the avatar at the zero pose with zero translation (pose-dependent terms included).
    """
    from trioman import __version__
    from trioman.runtime.ply import write_ply

    where = "save_avatar"
    target, inputs = Path(path), tuple(inputs)
    check_folder_target(target, overwrite, AVATAR_FOLDER, inputs)
    if not isinstance(skeleton, Skeleton):
        raise FormatError(f"{where}: skeleton: expected a Skeleton, got {type(skeleton).__name__}")
    positions = np.asarray(gaussians.get("positions", np.zeros((0, 3))))
    N = int(positions.shape[0]) if positions.ndim else 0
    anisotropic = "local_quats" in gaussians
    pose_joints = [str(j) for j in pose_joints]
    meta: dict[str, Any] = {
        "format": AVATAR_FORMAT,
        "version": 1 if pose_points is None else AVATAR_VERSION,
        "body_model": body_model,
        "units": "m",
        "num_gaussians": N,
        "anisotropic": anisotropic,
        "pose_dependent": pose_dependent_onnx is not None,
        "scale_clamp": list(SCALE_CLAMP),
        "pose_joints": pose_joints,
        **({} if pose_points is None else {"pose_points": pose_points}),
        "trioman_version": __version__,
        "source": plain_json(dict(source or {}), where, "source"),
        "files": {},
    }
    names = [GAUSSIANS_NPZ, SKELETON_NPZ, CANONICAL_PLY] + ([POSE_ONNX] if pose_dependent_onnx is not None else [])
    meta["files"] = {n: {"sha256": "0" * 64, "bytes": 0} for n in names}
    posed = dict(posed or {})
    for name in posed:
        meta["files"][f"posed_{name}.ply"] = {"sha256": "0" * 64, "bytes": 0}
    _check_meta(meta, where)
    _check_pose_joints(pose_joints, skeleton, where)
    arrays = _check_gaussians(gaussians, where, N, skeleton.num_joints, anisotropic, pose_points)
    unknown = sorted(set(gaussians) - set(arrays))
    if unknown:
        raise format_error(where, "gaussians", f"unknown array(s) {unknown}")
    session = None
    if pose_dependent_onnx is not None:
        session = _open_onnx(bytes(pose_dependent_onnx), f"{where}: {POSE_ONNX}", skeleton.num_joints, pose_points or N,
                             3 if anisotropic else 1)
    avatar = Avatar(skeleton, arrays, meta, session)

    with atomic_folder(target, overwrite, AVATAR_FOLDER, inputs) as tmp:
        write_npz(tmp / GAUSSIANS_NPZ, arrays)
        write_npz(tmp / SKELETON_NPZ, {"joint_names": np.array(skeleton.joint_names, dtype=np.str_),
                                        "parents": skeleton.parents, "joints": skeleton.joints})
        if pose_dependent_onnx is not None:
            write_synced(tmp / POSE_ONNX, bytes(pose_dependent_onnx))
        J = skeleton.num_joints
        write_ply(tmp / CANONICAL_PLY, *avatar.gaussians(np.zeros((J, 3)), np.zeros(3)))
        for name, (pose, trans) in posed.items():
            write_ply(tmp / f"posed_{name}.ply", *avatar.gaussians(pose, trans))
        for name in meta["files"]:
            meta["files"][name] = {"sha256": sha256_file(tmp / name), "bytes": (tmp / name).stat().st_size}
        write_synced(tmp / AVATAR_JSON, (json.dumps(meta, indent=2, allow_nan=False) + "\n").encode("utf-8"))
    return load_avatar(target)
