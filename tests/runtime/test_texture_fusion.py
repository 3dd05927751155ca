"""The fused texture against brute force: its image formation against mesh_raster's own texture lookup, its
solve against a dense least-squares solve, and textures made by that image formation recovered from their frames."""

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tests.runtime.painted_box import CENTER, FRONT, K, MESH, POSE, SIZE, TRANS
from trioman.runtime.aligned import AlignConfig, Aligner, SourceViews
from trioman.runtime.cameras import orbit_viewmat
from trioman.runtime.mesh_raster import interpolate, rasterize_mesh, sample_texture
from trioman.runtime.texture_fusion import SUPERSAMPLE, FusedTexture, _laplacian, fuse_texture, texel_rows

# the box with a UV layout: a cylindrical unwrap (u: angle about the long axis, v: height)
_V = MESH.vertices - [0.0, 0.0, 0.5]
_UV = np.stack([(np.arctan2(_V[:, 1], _V[:, 0]) / (2 * np.pi)) % 1.0, _V[:, 2] + 0.5], 1).astype(np.float32)
UV_MESH = dataclasses.replace(MESH, uvs=np.clip(_UV, 0.02, 0.98), uv_faces=np.asarray(MESH.faces))
CAMERAS = [orbit_viewmat(CENTER, a, 0.1, 3.0) for a in np.linspace(-0.6, 0.6, 7)]


def smooth_texture(size: int, seed: int = 0) -> np.ndarray:
    """A texture with detail at a few texels' scale. [size, size, 3]."""
    rng = np.random.default_rng(seed)
    t = rng.random((size // 4, size // 4, 3))
    return np.clip(np.kron(t, np.ones((4, 4, 1))) * 0.8 + 0.1, 0, 1).astype(np.float32)


def formation(texture: np.ndarray, viewmat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Brute force: SUPERSAMPLE^2 samples a pixel, each a bilinear texture lookup (sample_texture), box-filtered;
    -> (rgb [H, W, 3], whole [H, W]: every sample on the body)."""
    ss = SUPERSAMPLE
    Ks = K.copy()
    Ks[:2] *= ss
    frags = rasterize_mesh(UV_MESH.pose(POSE, TRANS), UV_MESH.faces, viewmat, Ks, SIZE * ss, SIZE * ss)
    colour = sample_texture(texture, interpolate(frags, UV_MESH.uvs, UV_MESH.uv_faces))
    rgb = colour.reshape(SIZE, ss, SIZE, ss, 3).mean(axis=(1, 3))
    whole = (frags.face_id >= 0).reshape(SIZE, ss, SIZE, ss).all(axis=(1, 3))
    return rgb, whole


def test_the_image_formation_is_mesh_rasters_texture_lookup():
    tex = smooth_texture(32)
    want, whole = formation(tex, FRONT)
    got, valid = FusedTexture(tex, np.ones((32, 32), np.float32)).render(UV_MESH, POSE, TRANS, FRONT, K, SIZE, SIZE, 0.5)
    assert whole.sum() > 200 and np.array_equal(valid, whole)
    np.testing.assert_allclose(got[whole], want[whole], atol=1e-5)
    pix, idx, w = texel_rows(UV_MESH, POSE, TRANS, FRONT, K, SIZE, SIZE, 32)
    np.testing.assert_allclose(w.sum(1), 1.0, atol=1e-6)
    assert idx.shape == (len(pix), 4 * SUPERSAMPLE**2) and idx.min() >= 0 and idx.max() < 32 * 32


def frames_of(tex: np.ndarray):
    made = [formation(tex, v) for v in CAMERAS]
    return lambda p: (POSE, TRANS, CAMERAS[p], K, made[p][0], made[p][1].astype(np.float32))


def test_the_solve_is_the_dense_least_squares_solution():
    size, smooth = 16, 0.05
    frame = frames_of(smooth_texture(size, 1))
    fused = fuse_texture(UV_MESH, len(CAMERAS), frame, size, smooth, iterations=5000, tol=1e-12)
    rows, b = [], []
    for p in range(len(CAMERAS)):
        pix, idx, w = texel_rows(UV_MESH, POSE, TRANS, CAMERAS[p], K, SIZE, SIZE, size)
        A = np.zeros((len(pix), size * size))
        np.add.at(A, (np.repeat(np.arange(len(pix)), idx.shape[1]), idx.reshape(-1)), w.reshape(-1))
        rows.append(A)
        b.append(frame(p)[4].reshape(-1, 3)[pix])
    A, b = np.concatenate(rows), np.concatenate(b)
    L = np.stack([_laplacian(e.reshape(size, size, 1)).reshape(-1) for e in np.eye(size * size)], 1)
    x = np.linalg.solve(A.T @ A + smooth * L, A.T @ b)
    assert np.ptp(x) > np.ptp(b)  # the exact solution overshoots the frames' range: the clip is tested too
    np.testing.assert_allclose(fused.texture.reshape(-1, 3), np.clip(x, b.min(), b.max()), atol=1e-4)
    np.testing.assert_allclose(fused.seen.reshape(-1), A.sum(0), rtol=1e-5)


def test_a_texture_seen_by_many_frames_is_recovered_and_renders_a_new_view():
    tex = smooth_texture(64, 2)
    fused = fuse_texture(UV_MESH, len(CAMERAS), frames_of(tex), 64, 1e-4, iterations=400)
    between = orbit_viewmat(CENTER, 0.35, 0.15, 2.7)  # a view no frame had
    want, _ = formation(tex, between)
    got, valid = fused.render(UV_MESH, POSE, TRANS, between, K, SIZE, SIZE, 0.05)
    assert valid.sum() > 0.8 * _.sum()
    err = np.sqrt(np.mean((got[valid] - want[valid]) ** 2))
    assert err < 0.02, err


def test_the_aligner_takes_the_fused_colour_where_seen_and_refuses_what_it_cannot_do():
    tex = smooth_texture(64, 3)
    made = [formation(tex, v) for v in CAMERAS]
    masks = [m.astype(np.float32) for _, m in made]
    views = SourceViews(lambda p: made[p][0] * masks[p][..., None], lambda p: masks[p], np.stack([POSE] * len(CAMERAS)),
                        np.zeros((len(CAMERAS), 3)), np.stack(CAMERAS), np.stack([K] * len(CAMERAS)), SIZE, SIZE)
    draw = orbit_viewmat(CENTER, 0.3, 0.2, 2.8)
    carried = Aligner(UV_MESH, views, AlignConfig(flow=False)).align(3, POSE, TRANS, draw, K)
    fused = Aligner(UV_MESH, views, AlignConfig(flow=False, texture=64)).align(3, POSE, TRANS, draw, K)
    want, whole = formation(tex, draw)
    assert (fused.valid >= carried.valid).all() and fused.valid[whole].mean() > 0.9
    sel = carried.valid & whole

    def rmse(x):
        return np.sqrt(np.mean((x[sel] - want[sel]) ** 2))

    assert rmse(fused.rgb) < rmse(carried.rgb)
    with pytest.raises(ValueError, match="exclude"):
        Aligner(UV_MESH, views, AlignConfig(texture=64)).align(3, POSE, TRANS, draw, K, exclude=[2])
    with pytest.raises(ValueError, match="UV"):
        Aligner(MESH, views, AlignConfig(texture=64)).align(3, POSE, TRANS, draw, K)
    with pytest.raises(ValueError, match="texture"):
        AlignConfig(texture=8)
    empty = frames_of(tex)
    with pytest.raises(ValueError, match="^frames: none of the 2 source frames"):
        fuse_texture(UV_MESH, 2, lambda p: (*empty(p)[:5], np.zeros((SIZE, SIZE), np.float32)), 32)


_EXTREME = st.sampled_from([0.0, 1.0, 1e-6, 1.0 - 1e-6, 0.5])


@settings(max_examples=12, deadline=None)
@given(st.lists(_EXTREME, min_size=len(CAMERAS), max_size=len(CAMERAS)), st.sampled_from([1e-8, 1e-3, 0.02, 1e3]),
       st.sampled_from([1, 20, 200]))
def test_extreme_frames_give_a_finite_texture(colours, smooth, iterations):
    """All-black, all-white and mixed frames, smoothness from none to overwhelming, few or many iterations: the
    texture is finite; frames of one colour give that colour everywhere (it solves the equations exactly)."""
    made = [formation(smooth_texture(32), v) for v in CAMERAS]

    def frame(p):
        return POSE, TRANS, CAMERAS[p], K, np.full((SIZE, SIZE, 3), colours[p], np.float32), made[p][1].astype(np.float32)

    fused = fuse_texture(UV_MESH, len(CAMERAS), frame, 32, smooth, iterations=iterations)
    assert np.isfinite(fused.texture).all() and np.isfinite(fused.seen).all()
    assert fused.texture.min() > -1.0 and fused.texture.max() < 2.0
    if len(set(colours)) == 1:
        np.testing.assert_allclose(fused.texture, colours[0], atol=1e-5)
