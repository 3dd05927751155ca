"""Tests of the numpy z-buffer rasterizer against a brute-force float64 reference."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import trioman.runtime.mesh_raster as mr
from trioman.runtime.mesh_raster import (
    Fragments,
    interpolate,
    rasterize_mesh,
    rasterize_screen,
    sample_texture,
    vertex_normals,
)

# ---------------------------------------------------------------------------------------------
# brute-force reference: every pixel against every triangle (vectorised over pixels), float64,
# nearest depth wins, strict < in increasing face order so the lower index wins ties.


def _edge(a, b, px, py):
    return (b[0] - a[0]) * (py - a[1]) - (b[1] - a[1]) * (px - a[0])


def ref_raster(xy, z, faces, width, height, perspective=True, cull=False):
    xy = np.asarray(xy, np.float64)
    z = np.asarray(z, np.float64)
    jj, ii = np.meshgrid(np.arange(width), np.arange(height))
    px, py = jj + 0.5, ii + 0.5
    face_id = np.full((height, width), -1)
    bary = np.zeros((height, width, 3))
    depth = np.full((height, width), np.inf)
    with np.errstate(all="ignore"):
        for f, tri in enumerate(np.asarray(faces).reshape(-1, 3)):
            p0, p1, p2 = xy[tri]
            zz = z[tri]
            area = _edge(p0, p1, p2[0], p2[1])
            if not np.isfinite(area) or area == 0 or (cull and area > 0):
                continue
            s = np.sign(area)
            w = [s * _edge(p1, p2, px, py), s * _edge(p2, p0, px, py), s * _edge(p0, p1, px, py)]
            wsum = w[0] + w[1] + w[2]
            inside = (w[0] >= 0) & (w[1] >= 0) & (w[2] >= 0) & (wsum > 0)
            # within the triangle's bounding box: for slivers thinner than float64 can resolve, the
            # edge functions round to 0 all along the sliver's line, far beyond its corners
            lo, hi = xy[tri].min(0), xy[tri].max(0)
            inside &= (px >= lo[0]) & (px <= hi[0]) & (py >= lo[1]) & (py <= hi[1])
            b = [wk / wsum for wk in w]
            c = 1.0 / zz if perspective else zz
            d = c[0] + b[1] * (c[1] - c[0]) + b[2] * (c[2] - c[0])
            if perspective:
                d = 1.0 / d
            upd = inside & np.isfinite(d) & (d < depth)
            depth[upd] = d[upd]
            face_id[upd] = f
            for k in range(3):
                bary[..., k][upd] = (b[k] * c[k] * d if perspective else b[k])[upd]
    return face_id, bary, depth


def assert_matches_ref(frags, ref, bary_atol=1e-5):
    face_id, bary, depth = ref
    np.testing.assert_array_equal(frags.face_id, face_id)
    cov = face_id >= 0
    np.testing.assert_allclose(frags.bary[cov], bary[cov], rtol=0, atol=bary_atol)
    np.testing.assert_allclose(frags.depth[cov], depth[cov], rtol=1e-6, atol=1e-5)
    assert np.all(frags.bary[~cov] == 0)
    assert np.all(np.isinf(frags.depth[~cov]))


def random_scene(seed, width=32, height=24, max_tris=60):
    """Overlapping triangles of mixed sizes and windings, some off screen, plus exact ties,
    degenerate triangles and edges through pixel centres."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, max_tris + 1))
    centre = rng.uniform([-6, -6], [width + 6, height + 6], size=(n, 1, 2))
    size = np.exp(rng.uniform(np.log(0.4), np.log(25.0), size=(n, 1, 1)))
    xy = (centre + size * rng.normal(size=(n, 3, 2))).reshape(-1, 2)
    z = rng.uniform(0.5, 5.0, size=3 * n)
    faces = np.arange(3 * n).reshape(n, 3)
    extra_xy, extra_z, extra_f = [], [], []
    v = 3 * n
    if seed % 2 == 0:  # a duplicated triangle: an exact tie everywhere, the lower index must win
        k = int(rng.integers(n))
        extra_f.append(faces[k])
    if seed % 3 == 0:  # two overlapping fronto-parallel triangles at the same depth
        extra_xy += [[2, 2], [20, 3], [5, 18], [4, 20], [25, 6], [28, 20]]
        extra_z += [2.0] * 6
        extra_f += [[v, v + 1, v + 2], [v + 3, v + 4, v + 5]]
        v += 6
    if seed % 4 == 1:  # half-integer vertices: edges pass exactly through pixel centres
        extra_xy += [[0.5, 0.5], [10.5, 0.5], [0.5, 10.5], [10.5, 10.5]]
        extra_z += [1.5, 1.5, 1.5, 1.5]
        extra_f += [[v, v + 1, v + 2], [v + 1, v + 3, v + 2]]
        v += 4
    if seed % 5 == 0:  # degenerate: collinear and repeated vertex
        extra_xy += [[1, 1], [10, 10], [20, 20]]
        extra_z += [0.1, 0.1, 0.1]
        extra_f += [[v, v + 1, v + 2], [v, v, v + 1]]
        v += 3
    if extra_xy:
        xy = np.concatenate([xy, np.asarray(extra_xy, np.float64)])
        z = np.concatenate([z, extra_z])
    if extra_f:
        faces = np.concatenate([faces, np.asarray(extra_f)])
    perm = rng.permutation(len(faces))
    return xy, z, faces[perm]


# ---------------------------------------------------------------------------------------------
# rasterize_screen


@pytest.mark.parametrize("seed", range(20))
def test_screen_matches_reference(seed):
    xy, z, faces = random_scene(seed)
    frags = rasterize_screen(xy, z, faces, 32, 24)
    assert_matches_ref(frags, ref_raster(xy, z, faces, 32, 24))


@pytest.mark.parametrize("seed", range(20, 30))
def test_screen_affine_matches_reference(seed):
    xy, z, faces = random_scene(seed)
    z = z - 2.0  # affine mode accepts any finite z
    frags = rasterize_screen(xy, z, faces, 32, 24, perspective=False)
    assert_matches_ref(frags, ref_raster(xy, z, faces, 32, 24, perspective=False))


@pytest.mark.parametrize("seed", range(30, 40))
def test_screen_backface_culling_matches_reference(seed):
    xy, z, faces = random_scene(seed)
    frags = rasterize_screen(xy, z, faces, 32, 24, cull_backfaces=True)
    assert_matches_ref(frags, ref_raster(xy, z, faces, 32, 24, cull=True))


def test_output_types_and_shapes():
    xy, z, faces = random_scene(3)
    frags = rasterize_screen(xy, z, faces, 17, 9)
    assert isinstance(frags, Fragments)
    assert frags.face_id.shape == (9, 17) and frags.face_id.dtype == np.int32
    assert frags.bary.shape == (9, 17, 3) and frags.bary.dtype == np.float32
    assert frags.depth.shape == (9, 17) and frags.depth.dtype == np.float32


def test_known_coverage_and_edges_inclusive():
    # x + y <= 4 for pixel centres: i + j <= 3 -> 10 pixels, the anti-diagonal lies on the edge
    xy = np.array([[0.0, 0.0], [4.0, 0.0], [0.0, 4.0]])
    frags = rasterize_screen(xy, np.ones(3), [[0, 1, 2]], 4, 4)
    ii, jj = np.mgrid[0:4, 0:4]
    np.testing.assert_array_equal(frags.face_id == 0, ii + jj <= 3)
    np.testing.assert_allclose(frags.bary.sum(-1)[ii + jj <= 3], 1.0, atol=1e-6)
    # pixel (0, 0) centre (0.5, 0.5): screen barycentrics (1 - 0.25, 0.125, 0.125)
    np.testing.assert_allclose(frags.bary[0, 0], [0.75, 0.125, 0.125], atol=1e-7)


def test_shared_edge_tie_goes_to_lower_index():
    # a square split along its diagonal, constant depth: every pixel once, diagonal to face 0
    xy = np.array([[0.5, 0.5], [8.5, 0.5], [0.5, 8.5], [8.5, 8.5]])
    upper, lower = [0, 1, 2], [1, 3, 2]
    ii, jj = np.mgrid[0:9, 0:9]
    diag = ii + jj == 8  # pixel centres exactly on the shared edge
    for order in ([upper, lower], [lower, upper]):
        frags = rasterize_screen(xy, np.full(4, 2.0), order, 9, 9)
        assert np.all(frags.face_id >= 0)
        assert np.all(frags.face_id[diag] == 0)
        assert np.all(frags.face_id[ii + jj < 8] == (0 if order[0] == upper else 1))
        np.testing.assert_array_equal(frags.depth, 2.0)


def test_nearest_wins_and_duplicate_tie():
    xy = np.array([[-1, -1], [20, -1], [-1, 20]], np.float64)  # covers the whole 6 x 6 image
    z = np.r_[[3.0] * 3, [1.0] * 3]
    far = rasterize_screen(np.concatenate([xy, xy]), z, [[0, 1, 2], [3, 4, 5]], 6, 6)
    assert set(np.unique(far.face_id)) == {1}
    dup = rasterize_screen(xy, np.full(3, 1.0), [[0, 1, 2], [0, 1, 2], [2, 0, 1]], 6, 6)
    assert set(np.unique(dup.face_id)) == {0}


@pytest.mark.parametrize("budget", [None, 7])
def test_equal_depth_lower_index_wins_across_batches(monkeypatch, budget):
    # coplanar constant-depth triangles of different sizes land in different internal batches;
    # whichever is processed first, the lower face index must win every tied pixel
    if budget:
        monkeypatch.setattr(mr, "_MAX_CANDIDATES", budget)
    big = [[0.0, 0.0], [16.0, 0.0], [0.0, 16.0]]
    small = [[1.0, 1.0], [5.0, 1.0], [1.0, 5.0]]
    xy = np.array(big + small)
    small_px = rasterize_screen(np.array(small), np.ones(3), [[0, 1, 2]], 16, 16).face_id == 0
    for perspective in (True, False):
        a = rasterize_screen(xy, np.full(6, 2.0), [[0, 1, 2], [3, 4, 5]], 16, 16, perspective=perspective)
        assert small_px.sum() > 5 and np.all(a.face_id[small_px] == 0)
        b = rasterize_screen(xy, np.full(6, 2.0), [[3, 4, 5], [0, 1, 2]], 16, 16, perspective=perspective)
        assert np.all(b.face_id[small_px] == 0) and np.all(b.face_id[~small_px & (a.face_id == 0)] == 1)


def test_degenerate_and_offscreen_cover_nothing():
    xy = np.array([[1, 1], [5, 5], [9, 9], [-50, -50], [-40, -50], [-50, -40]], np.float64)
    frags = rasterize_screen(xy, np.ones(6), [[0, 1, 2], [0, 0, 1], [3, 4, 5]], 12, 12)
    assert np.all(frags.face_id == -1)


def test_empty_faces_give_empty_fragments():
    for faces in (np.zeros((0, 3), np.int64), []):
        frags = rasterize_screen(np.zeros((0, 2)), np.zeros(0), faces, 5, 4)
        assert frags.face_id.shape == (4, 5) and np.all(frags.face_id == -1)
        assert np.all(np.isinf(frags.depth)) and np.all(frags.bary == 0)


def test_backface_convention_screen():
    # counter-clockwise as displayed (y down): area < 0 -> front face, kept when culling
    ccw = np.array([[1, 1], [1, 9], [9, 9]], np.float64)
    cw = ccw[::-1].copy()
    assert (rasterize_screen(ccw, np.ones(3), [[0, 1, 2]], 10, 10, cull_backfaces=True).face_id == 0).any()
    assert (rasterize_screen(cw, np.ones(3), [[0, 1, 2]], 10, 10, cull_backfaces=True).face_id == -1).all()
    a = rasterize_screen(ccw, np.ones(3), [[0, 1, 2]], 10, 10)
    b = rasterize_screen(cw, np.ones(3), [[0, 1, 2]], 10, 10)
    np.testing.assert_array_equal(a.face_id, b.face_id)  # without culling both windings draw


def test_deterministic_and_independent_of_chunking(monkeypatch):
    xy, z, faces = random_scene(8, 64, 48, 60)
    xy = xy * 2.0
    big = np.array([[-100, -100], [300, -50], [-20, 300]], np.float64)  # covers the whole image
    xy = np.concatenate([xy, big])
    z = np.concatenate([z, [4.0, 4.5, 5.0]])
    faces = np.concatenate([faces, [[len(xy) - 3, len(xy) - 2, len(xy) - 1]]])
    a = rasterize_screen(xy, z, faces, 64, 48)
    b = rasterize_screen(xy, z, faces, 64, 48)
    monkeypatch.setattr(mr, "_MAX_CANDIDATES", 7)
    monkeypatch.setattr(mr, "_MAX_ROWS", 5)
    c = rasterize_screen(xy, z, faces, 64, 48)
    for x, y in ((a, b), (a, c)):
        for f in Fragments._fields:
            assert getattr(x, f).tobytes() == getattr(y, f).tobytes()
    assert_matches_ref(c, ref_raster(xy, z, faces, 64, 48))


def test_uv_bake_covers_unit_square_once():
    # a UV layout: two triangles tiling [0, W] x [0, H], affine, z = 1
    W, H = 16, 8
    xy = np.array([[0, 0], [W, 0], [0, H], [W, H]], np.float64)
    frags = rasterize_screen(xy, np.ones(4), [[0, 1, 2], [1, 3, 2]], W, H, perspective=False)
    assert np.all(frags.face_id >= 0)
    np.testing.assert_array_equal(frags.depth, 1.0)
    # affine interpolation of a linear function of the screen position reproduces it
    g = lambda x, y: 3.0 * x - 2.0 * y + 1.0  # noqa: E731
    val = interpolate(frags, g(xy[:, 0], xy[:, 1])[:, None], [[0, 1, 2], [1, 3, 2]])[..., 0]
    jj, ii = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    np.testing.assert_allclose(val, g(jj, ii), atol=1e-4)


# ---------------------------------------------------------------------------------------------
# rasterize_mesh


def random_rotation(rng):
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q *= np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def project_by_hand(vertices, viewmat, K):
    cam = vertices @ viewmat[:3, :3].T + viewmat[:3, 3]
    X, Y, Z = cam.T
    u = K[0, 0] * (X / Z) + K[0, 1] * (Y / Z) + K[0, 2]
    v = K[1, 1] * (Y / Z) + K[1, 2]
    return np.stack([u, v], 1), Z, cam


@pytest.mark.parametrize("seed", range(12))
def test_mesh_matches_projection_and_reference(seed):
    rng = np.random.default_rng(100 + seed)
    W, H = 32, 24
    n = int(rng.integers(1, 50))
    R = random_rotation(rng)
    viewmat = np.eye(4)
    viewmat[:3, :3] = R
    viewmat[:3, 3] = rng.normal(size=3)
    K = np.array([[30.0, rng.uniform(-2, 2), 16.0], [0.0, 28.0, 12.0], [0.0, 0.0, 1.0]])
    # triangles around camera-space points, some crossing the near plane or beyond far
    centres = np.c_[rng.uniform(-0.8, 0.8, (n, 2)), rng.uniform(-0.5, 9.0, n)]
    cam = centres[:, None] + rng.normal(scale=0.4, size=(n, 3, 3))
    world = (cam.reshape(-1, 3) - viewmat[:3, 3]) @ R  # inverse of the view transform
    faces = np.arange(3 * n).reshape(n, 3)
    near, far = 0.3, 8.0
    frags = rasterize_mesh(world, faces, viewmat, K, W, H, near_plane=near, far_plane=far)
    xy, Z, _ = project_by_hand(world, viewmat, K)
    ok = np.all((Z[faces] >= near) & (Z[faces] <= far), axis=1)
    ref_xy = np.where(np.isfinite(xy), xy, 0.0)
    ref = ref_raster(ref_xy, np.where(Z > 0, Z, 1.0), faces[ok], W, H)
    kept = np.r_[np.nonzero(ok)[0], -1]  # reference row -> original face index, -1 -> -1
    face_id = kept[ref[0]]
    assert_matches_ref(frags, (face_id, ref[1], ref[2]))
    assert not np.isin(frags.face_id, np.nonzero(~ok)[0]).any()


@pytest.mark.parametrize("seed", range(4))
def test_mesh_perspective_correct_points_on_pixel_rays(seed):
    rng = np.random.default_rng(seed)
    W, H = 40, 30
    K = np.array([[35.0, 0.0, 20.0], [0.0, 35.0, 15.0], [0.0, 0.0, 1.0]])
    n = 20
    cam = np.c_[rng.uniform(-0.6, 0.6, (n, 2)), rng.uniform(1.0, 6.0, n)][:, None] + rng.normal(
        scale=[0.5, 0.5, 1.5], size=(n, 3, 3)
    )
    cam[..., 2] = np.maximum(cam[..., 2], 0.2)
    verts = cam.reshape(-1, 3)
    faces = np.arange(3 * n).reshape(n, 3)
    frags = rasterize_mesh(verts, faces, np.eye(4), K, W, H)
    cov = frags.face_id >= 0
    assert cov.sum() > 50
    P = interpolate(frags, verts, faces)[cov]  # camera-space surface points [N, 3]
    ii, jj = np.nonzero(cov)
    np.testing.assert_allclose(P[:, 0] / P[:, 2] * 35 + 20, jj + 0.5, atol=2e-3)
    np.testing.assert_allclose(P[:, 1] / P[:, 2] * 35 + 15, ii + 0.5, atol=2e-3)
    np.testing.assert_allclose(P[:, 2], frags.depth[cov], rtol=1e-5)


def _sphere_camera(W=64, H=48, dist=4.0, seed=0):
    rng = np.random.default_rng(seed)
    R = random_rotation(rng)
    viewmat = np.eye(4)
    viewmat[:3, :3] = R
    viewmat[:3, 3] = [0.0, 0.0, dist]  # sphere centre on the optical axis
    K = np.array([[60.0, 0.0, W / 2], [0.0, 60.0, H / 2], [0.0, 0.0, 1.0]])
    return viewmat, K


def test_mesh_backface_culling_keeps_camera_facing_triangles():
    sphere = trimesh.creation.icosphere(subdivisions=2)
    V, F = np.asarray(sphere.vertices), np.asarray(sphere.faces)
    viewmat, K = _sphere_camera()
    full = rasterize_mesh(V, F, viewmat, K, 64, 48)
    culled = rasterize_mesh(V, F, viewmat, K, 64, 48, cull_backfaces=True)
    assert (full.face_id >= 0).sum() > 500
    np.testing.assert_array_equal(full.face_id, culled.face_id)  # closed convex mesh
    # every drawn face faces the camera; back faces alone are never drawn
    eye = -viewmat[:3, :3].T @ viewmat[:3, 3]
    normals = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    facing = np.einsum("fk,fk->f", normals, eye - V[F].mean(1)) > 0
    assert facing[np.unique(culled.face_id[culled.face_id >= 0])].all()
    inside_out = rasterize_mesh(V, F[:, ::-1], viewmat, K, 64, 48, cull_backfaces=True)
    # with flipped winding only the far hemisphere's (now camera-facing) inner side is drawn
    drawn = inside_out.face_id >= 0
    assert drawn.sum() > 500
    assert (inside_out.depth[drawn] >= full.depth[drawn]).all()
    assert (inside_out.depth[drawn] > full.depth[drawn]).mean() > 0.9


def test_mesh_faces_behind_near_plane_dropped():
    verts = np.array([[-1, -1, 2], [1, -1, 2], [0, 1, 2], [-1, -1, 0.005], [1, -1, 3], [0, 1, 3]], float)
    K = np.array([[10.0, 0, 8], [0, 10.0, 8], [0, 0, 1]])
    frags = rasterize_mesh(verts, [[0, 1, 2], [3, 4, 5]], np.eye(4), K, 16, 16)
    assert set(np.unique(frags.face_id)) <= {-1, 0}
    frags = rasterize_mesh(verts, [[0, 1, 2], [3, 4, 5]], np.eye(4), K, 16, 16, far_plane=1.5)
    assert np.all(frags.face_id == -1)


# ---------------------------------------------------------------------------------------------
# interpolate, sample_texture, vertex_normals


def test_interpolate_linear_function_and_per_corner_index():
    sphere = trimesh.creation.icosphere(subdivisions=2)
    V, F = np.asarray(sphere.vertices), np.asarray(sphere.faces)
    viewmat, K = _sphere_camera()
    frags = rasterize_mesh(V, F, viewmat, K, 64, 48)
    A = np.array([[1.0, -2.0, 0.5], [0.3, 0.0, 1.0]])
    f = V @ A.T + [0.25, -1.0]  # linear in the world position
    got = interpolate(frags, f, F)
    pos = interpolate(frags, V, F)
    cov = frags.face_id >= 0
    np.testing.assert_allclose(got[cov], pos[cov] @ A.T + [0.25, -1.0], atol=1e-5)
    assert got.dtype == np.float32 and got.shape == (48, 64, 2)
    assert np.all(got[~cov] == 0)
    # the same as per-corner values with a per-corner index
    corner_vals = f[F].reshape(-1, 2)
    got2 = interpolate(frags, corner_vals, np.arange(3 * len(F)).reshape(-1, 3))
    np.testing.assert_allclose(got2, got, atol=1e-6)


def test_sample_texture_bilinear_and_v_up():
    tex = np.arange(4 * 3 * 2, dtype=np.float32).reshape(3, 4, 2)  # Ht=3, Wt=4, C=2
    # texel centres: (r, c) at u = (c + .5)/4, v = 1 - (r + .5)/3
    for r in range(3):
        for c in range(4):
            uv = [(c + 0.5) / 4, 1 - (r + 0.5) / 3]
            np.testing.assert_allclose(sample_texture(tex, uv), tex[r, c], atol=1e-5)
    # v = 0 is the bottom row, v = 1 the top row (clamped at the border)
    np.testing.assert_allclose(sample_texture(tex, [0.0, 0.0]), tex[2, 0])
    np.testing.assert_allclose(sample_texture(tex, [1.0, 1.0]), tex[0, 3])
    np.testing.assert_allclose(sample_texture(tex, [-3.0, 7.0]), tex[0, 0])
    # hand-computed bilinear: u=0.3 -> x = 0.7 (cols 0,1), v=0.6 -> y = 0.7 (rows 0,1)
    want = (0.3 * 0.3 * tex[0, 0] + 0.3 * 0.7 * tex[0, 1] + 0.7 * 0.3 * tex[1, 0] + 0.7 * 0.7 * tex[1, 1])
    np.testing.assert_allclose(sample_texture(tex, [0.3, 0.6]), want, atol=1e-5)
    # batch shapes and 2D textures
    uv = np.random.default_rng(0).uniform(-0.2, 1.2, size=(5, 7, 2))
    out = sample_texture(tex, uv)
    assert out.shape == (5, 7, 2) and out.dtype == np.float32
    np.testing.assert_allclose(sample_texture(tex[..., 1], uv), out[..., 1], atol=1e-6)
    assert sample_texture(np.ones((1, 1, 3)), uv).shape == (5, 7, 3)


def test_vertex_normals_sphere_and_degenerate():
    sphere = trimesh.creation.icosphere(subdivisions=3)
    V, F = np.asarray(sphere.vertices), np.asarray(sphere.faces)
    n = vertex_normals(V, F)
    assert n.shape == V.shape and n.dtype == np.float32
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-6)
    assert np.einsum("vk,vk->v", n, V / np.linalg.norm(V, axis=1, keepdims=True)).min() > 0.999
    np.testing.assert_allclose(vertex_normals(V, F[:, ::-1]), -n, atol=1e-6)
    # isolated vertex, zero-area face, tiny and huge faces: finite, zero where undefined
    verts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [5, 5, 5], [2, 2, 2], [3, 3, 3],
                      [0, 0, 1e-200], [1e-200, 0, 1e-200], [0, 1e-200, 1e-200]], float)
    nn = vertex_normals(verts, [[0, 1, 2], [4, 5, 4], [6, 7, 8]])
    assert np.isfinite(nn).all()
    np.testing.assert_allclose(nn[[0, 1, 2]], [[0, 0, 1]] * 3, atol=1e-7)
    np.testing.assert_array_equal(nn[[3, 4, 5]], 0.0)
    big = vertex_normals(np.array([[0, 0, 0], [1e200, 0, 0], [0, 1e200, 0]]), [[0, 1, 2]])
    np.testing.assert_allclose(big, [[0, 0, 1]] * 3)


# ---------------------------------------------------------------------------------------------
# extreme inputs


coord = st.one_of(
    st.floats(-40, 40, allow_nan=False),
    st.floats(-1e7, 1e7, allow_nan=False),
    st.sampled_from([-1e12, 1e12, 0.5, 8.5, 1e-9]),
)


@st.composite
def extreme_scenes(draw):
    n = draw(st.integers(1, 8))
    xy, z = [], []
    for _ in range(n):
        kind = draw(st.sampled_from(["free", "tiny", "huge"]))
        if kind == "free":
            pts = [[draw(coord), draw(coord)] for _ in range(3)]
        elif kind == "tiny":
            cx, cy = draw(st.floats(-2, 18)), draw(st.floats(-2, 14))
            e = draw(st.floats(1e-9, 0.7))
            a, b = draw(st.floats(-1, 1)), draw(st.floats(-1, 1))
            pts = [[cx, cy], [cx + e, cy + a * e], [cx + b * e, cy + e]]
        else:
            s = draw(st.floats(1e2, 1e9))
            pts = [[-s, -s], [3 * s, -s], [-s, 3 * s]]
            if draw(st.booleans()):
                pts = pts[::-1]
        xy += pts
        z += [draw(st.floats(1e-3, 1e3)) for _ in range(3)]
    return np.asarray(xy, np.float64), np.asarray(z), np.arange(3 * n).reshape(n, 3)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(scene=extreme_scenes(), perspective=st.booleans(), cull=st.booleans())
def test_extreme_screen_inputs_finite(scene, perspective, cull):
    xy, z, faces = scene
    W, H = 16, 12
    frags = rasterize_screen(xy, z, faces, W, H, perspective=perspective, cull_backfaces=cull)
    cov = frags.face_id >= 0
    assert frags.face_id.min() >= -1 and frags.face_id.max() < len(faces)
    assert np.isfinite(frags.bary).all() and np.isfinite(frags.depth[cov]).all()
    assert (frags.bary[cov] >= -1e-6).all() and (frags.bary[cov] <= 1 + 1e-6).all()
    np.testing.assert_allclose(frags.bary[cov].sum(-1), 1.0, atol=1e-4)
    zf = z[faces[frags.face_id[cov]]]
    assert (frags.depth[cov] >= zf.min(1) * (1 - 1e-5)).all()
    assert (frags.depth[cov] <= zf.max(1) * (1 + 1e-5)).all()
    ref = ref_raster(xy, z, faces, W, H, perspective=perspective, cull=cull)
    np.testing.assert_array_equal(frags.face_id, ref[0])


@settings(max_examples=40, deadline=None)
@given(
    verts=st.lists(
        st.tuples(st.floats(-1e4, 1e4), st.floats(-1e4, 1e4), st.floats(-10, 10)), min_size=3, max_size=18
    ),
    near=st.sampled_from([1e-6, 0.01, 1.0]),
)
def test_extreme_mesh_inputs_finite(verts, near):
    V = np.asarray(verts, np.float64)
    n = len(V) // 3
    faces = np.arange(3 * n).reshape(n, 3)
    K = np.array([[20.0, 0, 8], [0, 20.0, 6], [0, 0, 1]])
    frags = rasterize_mesh(V, faces, np.eye(4), K, 16, 12, near_plane=near)
    cov = frags.face_id >= 0
    assert np.isfinite(frags.bary).all() and np.isfinite(frags.depth[cov]).all()
    assert (frags.depth[cov] >= near * (1 - 1e-6)).all()
    behind = (V[faces][..., 2] < near).any(1)
    assert not np.isin(frags.face_id, np.nonzero(behind)[0]).any()


# ---------------------------------------------------------------------------------------------
# validation

_XY = np.array([[0.0, 0.0], [4.0, 0.0], [0.0, 4.0]])
_F = np.array([[0, 1, 2]])


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(xy=np.array([[0.0, np.nan], [4, 0], [0, 4]])), r"xy: 1 non-finite"),
        (dict(xy=np.array([[np.inf, 0.0], [4, np.inf], [0, 4]])), r"xy: 2 non-finite"),
        (dict(xy=np.zeros((3, 3))), r"xy: expected shape \[V, 2\], got \[3, 3\]"),
        (dict(z=np.ones(2)), r"z: expected shape \[3\], got \[2\]"),
        (dict(z=np.array([1.0, np.nan, 1.0])), r"z: 1 non-finite"),
        (dict(z=np.array([1.0, 0.0, -1.0])), r"z: 2 values <= 0"),
        (dict(faces=np.array([[0, 1, 3]])), r"faces: 1 indices outside \[0, 3\)"),
        (dict(faces=np.array([[0, -1, 2], [5, 1, 2]])), r"faces: 2 indices outside"),
        (dict(faces=np.array([0, 1, 2])), r"faces: expected shape \[F, 3\], got \[3\]"),
        (dict(faces=np.array([[0.0, 1.0, 2.0]])), r"faces: expected an integer array"),
        (dict(width=0), r"width: must be a positive integer, got 0"),
        (dict(height=-3), r"height: must be a positive integer, got -3"),
        (dict(width=2.5), r"width: must be a positive integer, got 2.5"),
    ],
)
def test_screen_validation(kwargs, match):
    args = dict(xy=_XY, z=np.ones(3), faces=_F, width=8, height=8)
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        rasterize_screen(**args)


def test_screen_affine_accepts_nonpositive_z():
    frags = rasterize_screen(_XY, np.array([0.0, -1.0, 1.0]), _F, 8, 8, perspective=False)
    assert (frags.face_id == 0).any()


_V3 = np.array([[0.0, 0.0, 2.0], [1.0, 0.0, 2.0], [0.0, 1.0, 2.0]])
_K = np.array([[10.0, 0, 4], [0, 10.0, 4], [0, 0, 1]])


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(vertices=np.array([[0.0, 0, np.nan], [1, 0, 2], [0, 1, 2]])), r"vertices: 1 non-finite"),
        (dict(vertices=np.zeros((3, 2))), r"vertices: expected shape \[V, 3\]"),
        (dict(faces=np.array([[0, 1, 9]])), r"faces: 1 indices outside \[0, 3\)"),
        (dict(viewmat=np.eye(3)), r"viewmat: expected shape \[4, 4\], got \[3, 3\]"),
        (dict(viewmat=np.full((4, 4), np.inf)), r"viewmat: 16 non-finite"),
        (dict(K=np.eye(4)), r"K: expected shape \[3, 3\], got \[4, 4\]"),
        (dict(K=np.array([[np.nan, 0, 4], [0, 10.0, 4], [0, 0, 1]])), r"K: 1 non-finite"),
        (dict(width=-1), r"width: must be a positive integer, got -1"),
        (dict(height=0), r"height: must be a positive integer, got 0"),
        (dict(near_plane=0.0), r"near_plane: must be finite and > 0, got 0.0"),
        (dict(near_plane=1.0, far_plane=0.5), r"far_plane: must be > near_plane"),
    ],
)
def test_mesh_validation(kwargs, match):
    args = dict(vertices=_V3, faces=_F, viewmat=np.eye(4), K=_K, width=8, height=8)
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        rasterize_mesh(**args)


def test_interpolate_texture_normals_validation():
    frags = rasterize_screen(_XY, np.ones(3), _F, 8, 8)
    with pytest.raises(ValueError, match=r"values: 1 non-finite"):
        interpolate(frags, np.array([[0.0], [np.nan], [1.0]]), _F)
    with pytest.raises(ValueError, match=r"values: expected shape \[A, C\], got \[3\]"):
        interpolate(frags, np.zeros(3), _F)
    with pytest.raises(ValueError, match=r"corner_index: 1 indices outside \[0, 3\)"):
        interpolate(frags, np.zeros((3, 2)), [[0, 1, 3]])
    with pytest.raises(ValueError, match=r"corner_index: has 1 faces but frags reference face 1"):
        two = rasterize_screen(_XY, np.ones(3), [[0, 1, 2], [0, 1, 2]], 8, 8)
        two = two._replace(face_id=np.where(two.face_id >= 0, 1, -1).astype(np.int32))
        interpolate(two, np.zeros((3, 2)), _F)
    with pytest.raises(ValueError, match=r"frags: expected face_id \[H, W\]"):
        interpolate(frags._replace(bary=frags.bary[..., :2]), np.zeros((3, 2)), _F)
    with pytest.raises(ValueError, match=r"uv: 1 non-finite"):
        sample_texture(np.ones((2, 2, 3)), np.array([[0.5, np.nan]]))
    with pytest.raises(ValueError, match=r"uv: expected shape \[\.\.\., 2\], got \[4, 3\]"):
        sample_texture(np.ones((2, 2, 3)), np.zeros((4, 3)))
    with pytest.raises(ValueError, match=r"texture: 1 non-finite"):
        sample_texture(np.array([[[np.inf]]]), np.zeros(2))
    with pytest.raises(ValueError, match=r"texture: expected a non-empty"):
        sample_texture(np.ones((0, 2, 3)), np.zeros(2))
    with pytest.raises(ValueError, match=r"vertices: 1 non-finite"):
        vertex_normals(np.array([[0.0, 0, 0], [1, 0, 0], [0, np.inf, 0]]), _F)
    with pytest.raises(ValueError, match=r"faces: 1 indices outside"):
        vertex_normals(np.zeros((3, 3)), [[0, 1, 3]])
