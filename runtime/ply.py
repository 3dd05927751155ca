"""The standard 3D Gaussian Splatting .ply (INRIA gaussian-splatting / gsplat layout), in numpy.

Binary little endian, one ``vertex`` element of float32 properties, stored PRE-activation:

    x y z  f_dc_0 f_dc_1 f_dc_2  opacity  scale_0 scale_1 scale_2  rot_0 rot_1 rot_2 rot_3

opacity is a logit, scale_* a log scale, rot_* a wxyz quaternion, colour = 0.28209479177387814 *
f_dc + 0.5 (degree-0 spherical harmonics). Common splat viewers open these files. ``read_ply``
also accepts files with more properties (normals, f_rest_*, ...), which it ignores.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from trioman.runtime.formats.common import FormatError, require_file
from trioman.runtime.gaussians import Gaussians
from trioman.runtime.outputs import atomic_write_bytes

SH_C0 = 0.28209479177387814
PROPERTIES = ("x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1", "scale_2",
              "rot_0", "rot_1", "rot_2", "rot_3")
OPACITY_EPS = 1e-7  # opacity is clipped to [eps, 1 - eps] so its logit is finite
_TYPES = {"float": "<f4", "float32": "<f4", "double": "<f8", "float64": "<f8", "char": "i1", "int8": "i1",
          "uchar": "u1", "uint8": "u1", "short": "<i2", "int16": "<i2", "ushort": "<u2", "uint16": "<u2",
          "int": "<i4", "int32": "<i4", "uint": "<u4", "uint32": "<u4"}
_MAX_HEADER = 1 << 16


def _check(name: str, a: np.ndarray, cols: int | None, N: int | None) -> np.ndarray:
    a = np.asarray(a, dtype=np.float64)
    want = (N if N is not None else a.shape[0] if a.ndim else 0,) + ((cols,) if cols else ())
    if a.ndim != len(want) or a.shape != want:
        raise ValueError(f"{name}: expected shape {list(want)}, got {list(a.shape)}")
    bad = ~np.isfinite(a)
    if bad.any():
        raise ValueError(f"{name}: {int(bad.sum())} non-finite value(s) (NaN/Inf)")
    return a


def ply_bytes(means: np.ndarray,  # [N, 3]
              quats: np.ndarray,  # [N, 4] wxyz
              scales: np.ndarray,  # [N, 3] activated, > 0
              opacities: np.ndarray,  # [N] in [0, 1]
              colors: np.ndarray,  # [N, 3] in [0, 1]
              ) -> bytes:
    """Activated Gaussians -> the bytes of a 3DGS .ply."""
    means = _check("means", means, 3, None)
    N = len(means)
    quats = _check("quats", quats, 4, N)
    scales = _check("scales", scales, 3, N)
    opacities = _check("opacities", opacities, None, N)
    colors = _check("colors", colors, 3, N)
    if np.any(scales <= 0):
        raise ValueError(f"scales: {int((scales <= 0).sum())} non-positive value(s); scales must be > 0")
    if np.any((opacities < 0) | (opacities > 1)):
        raise ValueError("opacities: values must lie in [0, 1]")
    o = np.clip(opacities, OPACITY_EPS, 1 - OPACITY_EPS)
    data = np.empty((N, len(PROPERTIES)), dtype="<f4")
    data[:, 0:3] = means
    data[:, 3:6] = (colors - 0.5) / SH_C0
    data[:, 6] = np.log(o) - np.log1p(-o)
    data[:, 7:10] = np.log(scales)
    data[:, 10:14] = quats
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {N}"]
    header += [f"property float {p}" for p in PROPERTIES] + ["end_header"]
    return ("\n".join(header) + "\n").encode("ascii") + data.tobytes()


def write_ply(path: str | os.PathLike, means: np.ndarray, quats: np.ndarray, scales: np.ndarray,
              opacities: np.ndarray, colors: np.ndarray) -> Path:
    """Write activated Gaussians (the renderer's arguments, e.g. ``write_ply(path, *gaussians)``) atomically."""
    path = Path(path)
    atomic_write_bytes(path, ply_bytes(means, quats, scales, opacities, colors))
    return path


def read_ply(path: str | os.PathLike) -> Gaussians:
    """Read a 3DGS .ply -> activated Gaussians (float32): exp scales, sigmoid opacities, unit quats
    (zero quaternion -> identity), colours clipped to [0, 1]. Raises FormatError naming file and field."""
    path = Path(path)
    require_file(path)
    raw = path.read_bytes()
    end = raw.find(b"end_header\n", 0, _MAX_HEADER)
    if not raw.startswith(b"ply\n") or end < 0:
        raise FormatError(f"{path}: not a PLY file (expected 'ply' ... 'end_header' at the start)")
    body = end + len(b"end_header\n")
    try:
        lines = raw[:end].decode("ascii").splitlines()[1:]
    except UnicodeDecodeError:
        raise FormatError(f"{path}: header: not ASCII") from None
    fmt, count, props, element = None, None, [], None
    for line in lines:
        words = line.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "format":
            fmt = " ".join(words[1:])
        elif words[0] == "element":
            if len(words) != 3 or not words[2].isdigit():
                raise FormatError(f"{path}: header: malformed element line {line!r}")
            if element == "vertex":
                raise FormatError(f"{path}: header: element {words[1]!r} after 'vertex' (a 3DGS .ply has only vertices)")
            element = words[1]
            if element == "vertex":
                count = int(words[2])
        elif words[0] == "property":
            if element != "vertex":
                continue
            if len(words) != 3 or words[1] not in _TYPES:
                raise FormatError(f"{path}: header: unsupported property line {line!r}")
            props.append((words[2], _TYPES[words[1]]))
        else:
            raise FormatError(f"{path}: header: unknown line {line!r}")
    if fmt != "binary_little_endian 1.0":
        raise FormatError(f"{path}: format: expected 'binary_little_endian 1.0', got {fmt!r}")
    if count is None:
        raise FormatError(f"{path}: header: no 'element vertex N' line")
    names = [p for p, _ in props]
    missing = [p for p in PROPERTIES if p not in names]
    if missing:
        raise FormatError(f"{path}: vertex: missing propert{'y' if len(missing) == 1 else 'ies'} {missing}")
    if len(set(names)) != len(names):
        raise FormatError(f"{path}: vertex: duplicate property names")
    dtype = np.dtype(props)
    need = count * dtype.itemsize
    if len(raw) - body < need:
        raise FormatError(f"{path}: truncated: {count} vertices need {need} bytes of data, the file has {len(raw) - body}")
    if len(raw) - body > need:
        raise FormatError(f"{path}: {len(raw) - body - need} unexpected byte(s) after the {count} vertices")
    rec = np.frombuffer(raw, dtype=dtype, count=count, offset=body)
    cols = {p: rec[p].astype(np.float64) for p in PROPERTIES}
    for p, v in cols.items():
        bad = ~np.isfinite(v)
        if bad.any():
            raise FormatError(f"{path}: {p}: {int(bad.sum())} non-finite value(s) (NaN/Inf), first at vertex {int(np.flatnonzero(bad)[0])}")
    stack = lambda *ps: np.stack([cols[p] for p in ps], -1)  # noqa: E731
    q = stack("rot_0", "rot_1", "rot_2", "rot_3")
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    q = np.where(n > 0, q / np.where(n > 0, n, 1.0), np.array([1.0, 0.0, 0.0, 0.0]))
    opacity = 0.5 * (1.0 + np.tanh(0.5 * cols["opacity"]))
    f32 = np.float32
    return Gaussians(
        means=stack("x", "y", "z").astype(f32),
        quats=q.astype(f32),
        scales=np.exp(stack("scale_0", "scale_1", "scale_2")).astype(f32),
        opacities=opacity.astype(f32),
        colors=np.clip(SH_C0 * stack("f_dc_0", "f_dc_1", "f_dc_2") + 0.5, 0.0, 1.0).astype(f32),
    )
