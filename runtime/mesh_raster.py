"""Vectorised numpy z-buffer triangle rasterizer (no torch): ``rasterize_mesh``, ``rasterize_screen``.

Renders the synthetic subjects' meshes, bakes textures in UV space and draws body normal maps. Coverage,
winding, depth and tie rules: docs/design.md, "Mesh rasterizer".
"""

from __future__ import annotations

import numbers
from typing import NamedTuple

import numpy as np

__all__ = [
    "Fragments",
    "rasterize_screen",
    "rasterize_mesh",
    "interpolate",
    "sample_texture",
    "vertex_normals",
]

_MAX_CANDIDATES = 1 << 18  # candidate pixels evaluated at once (dense padded batch)
_MAX_ROWS = 1 << 19  # bounding-box rows expanded at once
_NO_FACE = np.iinfo(np.int32).max


class Fragments(NamedTuple):
    """Per-pixel result of a rasterization.

    face_id: [H, W] int32, index of the visible face, -1 where no triangle covers the pixel.
    bary:    [H, W, 3] float32, barycentrics of the visible point w.r.t. the face's corners
             (perspective-correct in perspective mode), 0 where empty.
    depth:   [H, W] float32, camera-space z of the visible surface, np.inf where empty.
    """

    face_id: np.ndarray  # [H, W] int32
    bary: np.ndarray  # [H, W, 3] float32
    depth: np.ndarray  # [H, W] float32


# --------------------------------------------------------------------------------------------
# validation


def _check_size(name: str, value) -> int:
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or int(value) <= 0:
        raise ValueError(f"{name}: must be a positive integer, got {value!r}")
    return int(value)


def _float_array(name: str, a, shape: tuple) -> np.ndarray:
    """Float64 array with the given shape (an int fixes a dim, a str names a free one); rejects
    NaN/Inf with a count."""
    try:
        arr = np.asarray(a, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name}: not convertible to a float array ({exc})") from None
    if arr.ndim != len(shape) or any(isinstance(s, int) and d != s for d, s in zip(arr.shape, shape)):
        want = "[" + ", ".join(str(s) for s in shape) + "]"
        raise ValueError(f"{name}: expected shape {want}, got {list(arr.shape)}")
    bad = arr.size - int(np.count_nonzero(np.isfinite(arr)))
    if bad:
        raise ValueError(f"{name}: {bad} non-finite (NaN/Inf) values")
    return arr


def _index_array(name: str, a, num_rows: int) -> np.ndarray:
    """[F, 3] int64 index array with every entry in [0, num_rows)."""
    arr = np.asarray(a)
    if arr.size == 0:
        arr = arr.reshape(-1, 3) if arr.ndim <= 1 or arr.shape[-1] == 3 else arr
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"{name}: expected shape [F, 3], got {list(arr.shape)}")
    if arr.size == 0:
        return np.zeros((0, 3), np.int64)
    if not np.issubdtype(arr.dtype, np.integer):
        raise ValueError(f"{name}: expected an integer array, got dtype {arr.dtype}")
    arr = arr.astype(np.int64, copy=False)
    bad = int(np.count_nonzero((arr < 0) | (arr >= num_rows)))
    if bad:
        raise ValueError(
            f"{name}: {bad} indices outside [0, {num_rows}) (min {int(arr.min())}, max {int(arr.max())})"
        )
    return arr


# --------------------------------------------------------------------------------------------
# rasterization


def rasterize_screen(
    xy: np.ndarray,  # [V, 2] pixel coordinates (x right, y down)
    z: np.ndarray,  # [V] depth (> 0 in perspective mode, smaller is closer)
    faces: np.ndarray,  # [F, 3] int
    width: int,
    height: int,
    perspective: bool = True,
    cull_backfaces: bool = False,
) -> Fragments:
    """Rasterize triangles given directly in pixel coordinates.

    Pixel (i, j) has its centre at x = j + 0.5, y = i + 0.5. ``perspective=True`` interpolates 1/z
    (perspective-correct barycentrics and depth) and needs z > 0; ``perspective=False`` interpolates
    z and the barycentrics affinely (texture baking in UV space: pass z = 1), any finite z.
    ``cull_backfaces`` drops triangles that are clockwise on screen (y down): docs/design.md, "Mesh rasterizer".

    Returns Fragments(face_id [H, W], bary [H, W, 3], depth [H, W]).
    Raises ValueError on NaN/Inf, wrong shapes, out-of-range face indices, bad width/height.
    """
    width = _check_size("width", width)
    height = _check_size("height", height)
    xy = _float_array("xy", xy, ("V", 2))
    num_verts = xy.shape[0]
    z = _float_array("z", z, (num_verts,))
    faces = _index_array("faces", faces, num_verts)
    if perspective:
        bad = int(np.count_nonzero(z <= 0))
        if bad:
            raise ValueError(f"z: {bad} values <= 0 (min {float(z.min())}); perspective mode needs z > 0")
    return _rasterize(xy, z, faces, None, width, height, bool(perspective), bool(cull_backfaces))


def rasterize_mesh(
    vertices: np.ndarray,  # [V, 3] world
    faces: np.ndarray,  # [F, 3] int
    viewmat: np.ndarray,  # [4, 4] world->camera
    K: np.ndarray,  # [3, 3] pixels
    width: int,
    height: int,
    near_plane: float = 0.01,
    far_plane: float = 1e10,
    cull_backfaces: bool = False,
) -> Fragments:
    """Rasterize a world-space mesh through an OpenCV pinhole camera (perspective-correct).

    Vertices are moved to camera space with ``viewmat`` and projected with x = fx X/Z + s Y/Z + cx,
    y = fy Y/Z + cy (the bottom row of K is taken to be [0, 0, 1]). There is no clipping: a triangle
    with any vertex at camera depth < near_plane or > far_plane is dropped entirely.
    ``face_id`` refers to rows of ``faces``; ``depth`` is camera-space Z.

    Returns Fragments(face_id [H, W], bary [H, W, 3], depth [H, W]).
    """
    width = _check_size("width", width)
    height = _check_size("height", height)
    vertices = _float_array("vertices", vertices, ("V", 3))
    faces = _index_array("faces", faces, vertices.shape[0])
    viewmat = _float_array("viewmat", viewmat, (4, 4))
    K = _float_array("K", K, (3, 3))
    near = float(near_plane)
    far = float(far_plane)
    if not (np.isfinite(near) and near > 0):
        raise ValueError(f"near_plane: must be finite and > 0, got {near_plane!r}")
    if not far > near:
        raise ValueError(f"far_plane: must be > near_plane ({near}), got {far_plane!r}")

    cam = vertices @ viewmat[:3, :3].T + viewmat[:3, 3]  # [V, 3]
    zc = cam[:, 2]
    ok_v = (zc >= near) & (zc <= far)
    zs = np.where(ok_v, zc, 1.0)
    xn = cam[:, 0] / zs
    yn = cam[:, 1] / zs
    xy = np.stack(
        [K[0, 0] * xn + K[0, 1] * yn + K[0, 2], K[1, 0] * xn + K[1, 1] * yn + K[1, 2]], axis=1
    )
    xy[~ok_v] = 0.0
    keep = np.nonzero(ok_v[faces].all(axis=1))[0]
    if keep.size == faces.shape[0]:
        return _rasterize(xy, zs, faces, None, width, height, True, bool(cull_backfaces))
    return _rasterize(xy, zs, faces[keep], keep, width, height, True, bool(cull_backfaces))


def _width_buckets(width: int) -> np.ndarray:
    """Padded row widths 1, 2, 3, 4, 6, 8, 12, 16, 24, ... (padding waste <= 1.5x), last >= width."""
    sizes = [1, 2, 3]
    p = 4
    while sizes[-1] < width:
        sizes += [p, p + p // 2]
        p *= 2
    return np.asarray(sizes, np.int64)


def _rasterize(
    xy: np.ndarray,  # [V, 2] float64
    z: np.ndarray,  # [V] float64
    faces: np.ndarray,  # [F, 3] int64
    face_ids: np.ndarray | None,  # [F] original face index of each row (increasing), None = arange
    width: int,
    height: int,
    perspective: bool,
    cull_backfaces: bool,
) -> Fragments:
    """Triangles are expanded into rows of their clipped pixel-centre bounding box, grouped by (padded)
    width and evaluated as dense [rows, width] arrays; inside fragments go into a float64 z-buffer with
    ``np.minimum.at`` (depth, then face index), and the winning face's barycentrics are recomputed once per
    covered pixel with the same arithmetic. At most ``_MAX_CANDIDATES`` candidate pixels are evaluated at
    once (a larger triangle is split into row bands), which bounds the working memory."""
    W, H = width, height
    tri_buf = np.full(H * W, _NO_FACE, np.int32)  # winning triangle (index into `faces`)
    depth_buf = np.full(H * W, np.inf, np.float64)
    bary = np.zeros((H * W, 3), np.float32)
    face_id = np.full(H * W, -1, np.int32)

    if faces.shape[0]:
        tx = xy[:, 0][faces]  # [F, 3]
        ty = xy[:, 1][faces]
        with np.errstate(over="ignore", invalid="ignore"):
            area = (tx[:, 1] - tx[:, 0]) * (ty[:, 2] - ty[:, 0]) - (ty[:, 1] - ty[:, 0]) * (
                tx[:, 2] - tx[:, 0]
            )
        keep = np.isfinite(area) & (area != 0)
        if cull_backfaces:
            keep &= area < 0
        # pixel-centre bounding box, clipped to the image (computed in float: vertices may be huge)
        j0 = np.maximum(np.ceil(tx.min(axis=1) - 0.5), 0.0)
        j1 = np.minimum(np.floor(tx.max(axis=1) - 0.5), W - 1.0)
        i0 = np.maximum(np.ceil(ty.min(axis=1) - 0.5), 0.0)
        i1 = np.minimum(np.floor(ty.max(axis=1) - 0.5), H - 1.0)
        keep &= (j1 >= j0) & (i1 >= i0)
        tris = np.nonzero(keep)[0]
        if tris.size:
            tz = z[faces]  # [F, 3]
            _raster_triangles(
                tris, tx, ty, tz, area, j0, j1, i0, i1, W, perspective, tri_buf, depth_buf
            )
            covered = np.flatnonzero(tri_buf != _NO_FACE)
            for c0 in range(0, covered.size, _MAX_CANDIDATES):  # bounded temporaries
                pix = covered[c0:c0 + _MAX_CANDIDATES]
                tri = tri_buf[pix]
                face_id[pix] = tri if face_ids is None else face_ids[tri]
                for k, col in enumerate(_bary_at(pix, tri, tx, ty, tz, W, perspective, depth_buf[pix])):
                    bary[pix, k] = col

    return Fragments(
        face_id.reshape(H, W),
        bary.reshape(H, W, 3),
        depth_buf.astype(np.float32).reshape(H, W),
    )


def _raster_triangles(tris, tx, ty, tz, area, j0, j1, i0, i1, W, perspective,
                      tri_buf, depth_buf) -> None:
    """Z-buffer the triangles `tris` (indices into the per-face arrays): nearest depth into
    `depth_buf`, its face row into `tri_buf` (both [H * W])."""
    s = np.sign(area[tris])
    # edge k goes a -> b with (a, b) = (p1, p2), (p2, p0), (p0, p1); w_k = dx (py - ay) - dy (px - ax)
    pairs = ((1, 2), (2, 0), (0, 1))
    ax = np.stack([tx[tris, a] for a, _ in pairs], axis=1)  # [T, 3]
    ay = np.stack([ty[tris, a] for a, _ in pairs], axis=1)
    dx = np.stack([s * (tx[tris, b] - tx[tris, a]) for a, b in pairs], axis=1)
    dy = np.stack([s * (ty[tris, b] - ty[tris, a]) for a, b in pairs], axis=1)
    zt = tz[tris]  # [T, 3]
    zc = 1.0 / zt if perspective else zt  # [T, 3] per-corner 1/z (perspective) or z (affine)
    lin = (zc[:, 0], zc[:, 1] - zc[:, 0], zc[:, 2] - zc[:, 0])  # 3 x [T]
    jt0 = j0[tris].astype(np.int64)
    nx = (j1[tris] - j0[tris]).astype(np.int64) + 1
    it0 = i0[tris].astype(np.int64)
    ny = (i1[tris] - i0[tris]).astype(np.int64) + 1
    buckets = _width_buckets(W)

    # chunks of whole triangles holding at most _MAX_ROWS rows (one huge triangle may exceed it by <= H)
    row_end = np.cumsum(ny)
    start = 0
    while start < tris.size:
        base = row_end[start - 1] if start else 0
        stop = max(int(np.searchsorted(row_end, base + _MAX_ROWS, side="right")), start + 1)
        sl = slice(start, stop)
        start = stop

        nyc = ny[sl]
        num_rows = int(nyc.sum())
        row_t = np.repeat(np.arange(sl.start, sl.stop), nyc)  # [R] index into the T arrays
        first = np.cumsum(nyc) - nyc
        row_i = it0[row_t] + (np.arange(num_rows) - np.repeat(first, nyc))
        row_nx = nx[row_t]
        # group rows by padded width, each group evaluated as a dense [rows, P] batch
        bucket = np.searchsorted(buckets, row_nx)
        order = np.argsort(bucket, kind="stable")
        counts = np.bincount(bucket, minlength=buckets.size)
        row_t, row_i, row_nx, bucket = row_t[order], row_i[order], row_nx[order], bucket[order]
        offs = np.concatenate([[0], np.cumsum(counts)])
        for b in np.nonzero(counts)[0]:
            P = int(buckets[b])
            step = max(1, _MAX_CANDIDATES // P)
            for r0 in range(int(offs[b]), int(offs[b + 1]), step):
                r1 = min(r0 + step, int(offs[b + 1]))
                _raster_rows(
                    row_t[r0:r1], row_i[r0:r1], row_nx[r0:r1], P, tris, jt0, ax, ay, dx, dy, lin,
                    W, perspective, tri_buf, depth_buf,
                )


def _raster_rows(row_t, row_i, row_nx, P, tris, jt0, ax, ay, dx, dy, lin, W, perspective,
                 tri_buf, depth_buf) -> None:
    """Evaluate a [rows, P] batch of candidate pixels and merge the inside ones into the z-buffer."""
    py = row_i + 0.5  # [R]
    rj0 = jt0[row_t]
    cols = np.arange(P)
    px = rj0[:, None] + (cols + 0.5)  # [R, P] float64, exact
    inside = cols < row_nx[:, None]  # [R, P] inside the clipped bbox
    w = [np.empty(px.shape) for _ in range(3)]
    ge = np.empty(px.shape, bool)
    with np.errstate(over="ignore", invalid="ignore"):
        for k in range(3):
            rk = dx[row_t, k] * (py - ay[row_t, k])  # [R]
            wk = w[k]
            np.subtract(px, ax[row_t, k][:, None], out=wk)
            np.multiply(wk, dy[row_t, k][:, None], out=wk)
            np.subtract(rk[:, None], wk, out=wk)  # dx (py - ay) - dy (px - ax)
            np.greater_equal(wk, 0.0, out=ge)
            inside &= ge
    flat = np.flatnonzero(inside)
    if flat.size == 0:
        return
    w0, w1, w2 = (wk.reshape(-1).take(flat) for wk in w)
    rr = flat // P
    t = row_t[rr]  # [M] index into the T arrays
    pix = row_i[rr] * W + rj0[rr] + (flat - rr * P)
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        wsum = w0 + w1 + w2
        d = lin[0][t] + (w1 / wsum) * lin[1][t] + (w2 / wsum) * lin[2][t]
        if perspective:
            d = 1.0 / d
    ok = (wsum > 0) & np.isfinite(d)
    if not ok.all():
        t, pix, d = t[ok], pix[ok], d[ok]
        if t.size == 0:
            return
    tri = tris[t].astype(np.int32)  # face row, the tie-break key

    # z-buffer merge, order independent: nearest wins, on equal depth the lower face index
    old_d = depth_buf[pix]
    old_t = tri_buf[pix]
    np.minimum.at(depth_buf, pix, d)
    cand = (d == depth_buf[pix]) & ((d < old_d) | (tri < old_t))
    pc, tc = pix[cand], tri[cand]
    tri_buf[pc] = _NO_FACE
    np.minimum.at(tri_buf, pc, tc)


def _bary_at(pix, tri, tx, ty, tz, W, perspective, depth) -> list[np.ndarray]:
    """3 x [N] barycentrics of face rows `tri` at pixels `pix`, recomputed with the exact
    arithmetic of the coverage pass (so they belong to the fragment that won the z-buffer)."""
    row = pix // W
    py = row + 0.5
    px = (pix - row * W) + 0.5
    x = [tx[:, k][tri] for k in range(3)]  # 3 x [N]
    y = [ty[:, k][tri] for k in range(3)]
    s = np.sign((x[1] - x[0]) * (y[2] - y[0]) - (y[1] - y[0]) * (x[2] - x[0]))
    w = [(s * (x[b] - x[a])) * (py - y[a]) - (s * (y[b] - y[a])) * (px - x[a])
         for a, b in ((1, 2), (2, 0), (0, 1))]
    scale = 1.0 / (w[0] + w[1] + w[2])
    if perspective:
        scale *= depth
        return [w[k] * scale / tz[:, k][tri] for k in range(3)]
    return [w[k] * scale for k in range(3)]


# --------------------------------------------------------------------------------------------
# attributes


def interpolate(
    frags: Fragments,
    values: np.ndarray,  # [A, C] attribute rows
    corner_index: np.ndarray,  # [F, 3] row of `values` for each face corner
) -> np.ndarray:  # [H, W, C] float32
    """Interpolate per-corner attributes with the fragments' barycentrics.

    For per-vertex attributes pass ``corner_index=faces``; for per-corner attributes (UVs with
    seams) pass the UV-face index array. Empty pixels get 0. Returns [H, W, C] float32.
    """
    face_id = np.asarray(frags.face_id)
    bary = np.asarray(frags.bary)
    if face_id.ndim != 2 or bary.shape != face_id.shape + (3,):
        raise ValueError(
            f"frags: expected face_id [H, W] and bary [H, W, 3], "
            f"got {list(face_id.shape)} and {list(bary.shape)}"
        )
    values = _float_array("values", values, ("A", "C"))
    corner_index = _index_array("corner_index", corner_index, values.shape[0])
    H, W = face_id.shape
    C = values.shape[1]
    out = np.zeros((H * W, C), np.float32)
    fid = face_id.reshape(-1)
    m = np.nonzero(fid >= 0)[0]
    if m.size == 0:
        return out.reshape(H, W, C)
    f = fid[m]
    if int(f.max()) >= corner_index.shape[0]:
        raise ValueError(
            f"corner_index: has {corner_index.shape[0]} faces but frags reference face {int(f.max())}"
        )
    idx = corner_index[f]  # [M, 3]
    b = bary.reshape(-1, 3)[m].astype(np.float64)
    acc = b[:, 0:1] * values[idx[:, 0]]
    acc += b[:, 1:2] * values[idx[:, 1]]
    acc += b[:, 2:3] * values[idx[:, 2]]
    out[m] = acc
    return out.reshape(H, W, C)


def sample_texture(
    texture: np.ndarray,  # [Ht, Wt, C] (or [Ht, Wt])
    uv: np.ndarray,  # [..., 2] u right, v up
) -> np.ndarray:  # [..., C] float32 (or [...] for a 2D texture)
    """Bilinear texture lookup, clamped to the border texels.

    u in [0, 1] runs left to right, v in [0, 1] bottom to top (OpenGL/Blender: v = 0 is the LAST
    row of the array). Texel (r, c) has its centre at u = (c + 0.5) / Wt, v = 1 - (r + 0.5) / Ht;
    uv outside the texel centres clamps to the edge texels.
    """
    tex = np.asarray(texture)
    if tex.ndim not in (2, 3) or 0 in tex.shape:
        raise ValueError(
            f"texture: expected a non-empty [Ht, Wt, C] or [Ht, Wt] array, got {list(tex.shape)}"
        )
    try:
        tex = tex.astype(np.float32, copy=False)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"texture: not convertible to a float array ({exc})") from None
    if not np.isfinite(tex).all():
        raise ValueError(f"texture: {int(np.count_nonzero(~np.isfinite(tex)))} non-finite (NaN/Inf) values")
    squeeze = tex.ndim == 2
    if squeeze:
        tex = tex[:, :, None]
    uv = np.asarray(uv, dtype=np.float64)
    if uv.ndim < 1 or uv.shape[-1] != 2:
        raise ValueError(f"uv: expected shape [..., 2], got {list(uv.shape)}")
    bad = uv.size - int(np.count_nonzero(np.isfinite(uv)))
    if bad:
        raise ValueError(f"uv: {bad} non-finite (NaN/Inf) values")
    Ht, Wt, C = tex.shape
    lead = uv.shape[:-1]
    uv = uv.reshape(-1, 2)
    x = np.clip(uv[:, 0] * Wt - 0.5, 0.0, Wt - 1.0)
    y = np.clip((1.0 - uv[:, 1]) * Ht - 0.5, 0.0, Ht - 1.0)
    xf = np.floor(x)
    yf = np.floor(y)
    x0 = xf.astype(np.int64)
    y0 = yf.astype(np.int64)
    dx1 = (x0 < Wt - 1).astype(np.int64)  # step to the right neighbour (0 on the last column)
    r0 = y0 * Wt + x0
    r1 = np.where(y0 < Ht - 1, r0 + Wt, r0)
    fx = (x - xf).astype(np.float32)[:, None]
    fy = (y - yf).astype(np.float32)[:, None]
    flat = tex.reshape(Ht * Wt, C)
    top = flat.take(r0, axis=0) * (1 - fx) + flat.take(r0 + dx1, axis=0) * fx
    bot = flat.take(r1, axis=0) * (1 - fx) + flat.take(r1 + dx1, axis=0) * fx
    out = top * (1 - fy) + bot * fy
    out = out.reshape(lead + (C,))
    return out[..., 0] if squeeze else out


def vertex_normals(
    vertices: np.ndarray,  # [V, 3]
    faces: np.ndarray,  # [F, 3] int
) -> np.ndarray:  # [V, 3] float32
    """Area-weighted vertex normals, unit length, float32.

    Each face contributes (v1 - v0) x (v2 - v0) (twice its area times its normal, outward for
    counter-clockwise faces) to its three vertices. A vertex whose contributions sum to zero
    (isolated vertex, only degenerate faces, cancelling faces) gets [0, 0, 0]; never NaN.
    """
    vertices = _float_array("vertices", vertices, ("V", 3))
    V = vertices.shape[0]
    faces = _index_array("faces", faces, V)
    scale = np.abs(vertices).max() if V else 0.0
    v = vertices / scale if scale > 0 else vertices  # normals are scale invariant; no overflow
    v0, v1, v2 = v[faces[:, 0]], v[faces[:, 1]], v[faces[:, 2]]
    fn = np.cross(v1 - v0, v2 - v0)  # [F, 3], |fn| <= 8
    flat = faces.reshape(-1)
    acc = np.stack(
        [np.bincount(flat, weights=np.repeat(fn[:, c], 3), minlength=V) for c in range(3)], axis=1
    )  # [V, 3]
    amax = np.abs(acc).max(axis=1, keepdims=True) if V else np.zeros((0, 1))
    nz = amax[:, 0] > 0
    out = np.zeros((V, 3), np.float64)
    a = acc[nz] / amax[nz]  # rescale first: no underflow in the norm
    out[nz] = a / np.linalg.norm(a, axis=1, keepdims=True)
    return out.astype(np.float32)
