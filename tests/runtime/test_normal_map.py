"""Body normal maps: encoding and axis signs, mask, background, degenerate geometry, bad input."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from trioman.runtime.cameras import intrinsics, look_at, orbit_viewmat
from trioman.runtime.generator import subject_center
from trioman.runtime.mesh_raster import rasterize_mesh
from trioman.runtime.normal_map import body_normal_map, normal_map
from trioman.runtime.skeleton import Skeleton, SkinnedMesh

SIZE = 33  # odd: the centre pixel (16, 16) lies on the optical axis
K = intrinsics(40.0, 40.0, SIZE / 2, SIZE / 2)
SPHERE = trimesh.creation.icosphere(subdivisions=3)
SV, SF = np.asarray(SPHERE.vertices), np.asarray(SPHERE.faces)
# A square at z = 2 in front of an identity camera, wound so its normal points at the camera (-z).
QUAD_V = np.array([[-1.0, -1.0, 2.0], [1.0, -1.0, 2.0], [1.0, 1.0, 2.0], [-1.0, 1.0, 2.0]])
QUAD_F = np.array([[0, 2, 1], [0, 3, 2]])


def _analytic_sphere(viewmat):
    """Encoded camera-space normals of the exact unit sphere at every pixel centre (NaN on a miss)."""
    jj, ii = np.meshgrid(np.arange(SIZE) + 0.5, np.arange(SIZE) + 0.5)
    rays = np.stack([(jj - K[0, 2]) / K[0, 0], (ii - K[1, 2]) / K[1, 1], np.ones_like(jj)], -1)
    R, t = viewmat[:3, :3], viewmat[:3, 3]
    d = rays @ R  # world directions (R^T d)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    o = -R.T @ t
    b = d @ o
    disc = b * b - (o @ o - 1.0)
    hit = o + (-b - np.sqrt(np.where(disc > 0, disc, np.nan)))[..., None] * d
    n_cam = hit @ R.T
    return (n_cam * [1.0, -1.0, -1.0] + 1.0) / 2.0


@pytest.mark.parametrize("azimuth, elevation", [(0.0, 0.0), (1.2, 0.4), (-2.5, -0.3)])
def test_sphere_matches_analytic_camera_space_normals(azimuth, elevation):
    viewmat = orbit_viewmat(np.zeros(3), azimuth, elevation, 3.0)
    out = normal_map(SV, SF, viewmat, K, SIZE, SIZE)
    assert out.rgb.dtype == np.float32 and out.rgb.shape == (SIZE, SIZE, 3) and out.mask.dtype == bool
    np.testing.assert_allclose(out.rgb[16, 16], [0.5, 0.5, 1.0], atol=0.01)  # faces the camera
    want = _analytic_sphere(viewmat)
    both = out.mask & np.isfinite(want[..., 0])
    assert both.sum() > 0.9 * out.mask.sum()
    np.testing.assert_allclose(out.rgb[both], want[both], atol=0.03)  # tessellation


def test_sides_have_the_right_signs():
    rgb = normal_map(SV, SF, look_at([0.0, -3.0, 0.0], np.zeros(3)), K, SIZE, SIZE).rgb
    right, left, up, down = rgb[16, 28], rgb[16, 4], rgb[4, 16], rgb[28, 16]
    assert right[0] > 0.8 and left[0] < 0.2 and abs(right[1] - 0.5) < 0.02 and abs(left[1] - 0.5) < 0.02
    assert up[1] > 0.8 and down[1] < 0.2 and abs(up[0] - 0.5) < 0.02 and abs(down[0] - 0.5) < 0.02
    assert min(right[2], left[2], up[2], down[2]) > 0.5


# (rotation axis, angle, channel, whether it rises above 0.5): turned about the camera's y axis by
# +0.5 the quad faces image-left (r < 0.5), by -0.7 image-right; about x by +0.4 image-down (g < 0.5).
@pytest.mark.parametrize("axis, angle, channel, above", [(1, 0.5, 0, False), (1, -0.7, 0, True), (0, 0.4, 1, False)])
def test_flat_quad_gives_one_exact_colour(axis, angle, channel, above):
    R = trimesh.transformations.rotation_matrix(angle, np.eye(3)[axis])[:3, :3]
    center = np.array([0.0, 0.0, 2.0])
    out = normal_map((QUAD_V - center) @ R.T + center, QUAD_F, np.eye(4), K, SIZE, SIZE)
    n = R @ [0.0, 0.0, -1.0]
    want = (np.array([n[0], -n[1], -n[2]]) + 1.0) / 2.0
    assert out.mask.sum() > 100 and (want[channel] > 0.5) == above
    np.testing.assert_allclose(out.rgb[out.mask], np.broadcast_to(want, (out.mask.sum(), 3)), atol=1e-6)


@pytest.mark.parametrize("background", [0.0, (0.2, 0.3, 0.4)])
def test_mask_matches_raster_and_background_is_constant(background):
    viewmat = orbit_viewmat(np.array([0.3, 0.0, 0.1]), 0.5, 0.2, 3.0)
    out = normal_map(SV, SF, viewmat, K, SIZE, SIZE, background=background)
    frags = rasterize_mesh(SV, SF, viewmat, K, SIZE, SIZE)
    np.testing.assert_array_equal(out.mask, frags.face_id >= 0)
    assert 0 < out.mask.sum() < SIZE * SIZE
    np.testing.assert_array_equal(out.rgb[~out.mask], np.broadcast_to(np.float32(background), ((~out.mask).sum(), 3)))
    assert out.rgb.min() >= 0 and out.rgb.max() <= 1


def test_degenerate_triangles_give_finite_output():
    viewmat = look_at([0.0, -3.0, 0.0], np.zeros(3))
    clean = normal_map(SV, SF, viewmat, K, SIZE, SIZE)
    # zero-area triangles (repeated and collinear corners) added to a sound mesh change nothing
    V = np.vstack([SV, [[0.0, -1.5, 0.0], [0.1, -1.5, 0.0], [0.2, -1.5, 0.0]]])
    extra = np.array([[len(SV), len(SV) + 1, len(SV) + 2], [0, 0, 1], [len(SV), len(SV), len(SV)]])
    dirty = normal_map(V, np.vstack([SF, extra]), viewmat, K, SIZE, SIZE)
    np.testing.assert_array_equal(dirty.rgb, clean.rgb)
    # only degenerate triangles: nothing covered, all background
    empty = normal_map(V, extra, viewmat, K, SIZE, SIZE, background=0.25)
    assert not empty.mask.any() and np.all(empty.rgb == 0.25)
    # a two-sided sheet: the vertex normals cancel to zero; the visible face's normal is used
    sheet = normal_map(QUAD_V, np.vstack([QUAD_F, QUAD_F[:, ::-1]]), np.eye(4), K, SIZE, SIZE)
    assert sheet.mask.any() and np.isfinite(sheet.rgb).all()
    np.testing.assert_allclose(sheet.rgb[sheet.mask], np.broadcast_to([0.5, 0.5, 1.0], (sheet.mask.sum(), 3)))


def _skinned_box() -> SkinnedMesh:
    box = trimesh.creation.box(extents=(0.4, 0.3, 1.0))
    V = np.asarray(box.vertices) + [0.0, 0.0, 0.5]
    sk = Skeleton(("root", "spine01"), np.array([-1, 0]), np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.5]]))
    w = np.stack([1.0 - V[:, 2], V[:, 2]], axis=1).astype(np.float32)
    return SkinnedMesh(sk, V, np.asarray(box.faces), np.tile([0, 1], (len(V), 1)), w)


def test_body_normal_map_renders_the_lbs_posed_mesh():
    mesh = _skinned_box()
    pose = np.array([[0.0, 0.0, 0.4], [0.3, 0.0, 0.0]])
    trans = np.array([0.1, 0.0, 0.0])
    viewmat = orbit_viewmat(np.array([0.0, 0.0, 0.5]), 0.2, 0.1, 3.0)
    got = body_normal_map(mesh, pose, trans, viewmat, K, SIZE, SIZE)
    want = normal_map(mesh.pose(pose, trans), mesh.faces, viewmat, K, SIZE, SIZE)
    np.testing.assert_array_equal(got.rgb, want.rgb)
    np.testing.assert_array_equal(got.mask, want.mask)
    assert got.mask.any()


def test_anny_body_normal_map(anny_body):  # skips without torch / anny
    mesh = anny_body.to_skinned_mesh()
    pose, trans = np.zeros((mesh.skeleton.num_joints, 3)), np.zeros(3)
    viewmat = orbit_viewmat(subject_center(mesh.skeleton, pose, trans), 0.0, 0.0, 3.0)
    out = body_normal_map(mesh, pose, trans, viewmat, intrinsics(100.0, 100.0, 24.0, 32.0), 48, 64)
    assert np.isfinite(out.rgb).all() and 300 < out.mask.sum() < 48 * 64 / 2
    assert np.median(out.rgb[out.mask][:, 2]) > 0.8  # the front of the body faces the camera


@pytest.mark.parametrize("kwargs, match", [
    ({"vertices": np.full((3, 3), np.nan)}, r"vertices: 9 non-finite"),
    ({"faces": np.array([[0, 1, 7]])}, r"faces: 1 indices outside \[0, 3\)"),
    ({"K": np.eye(4)}, r"K: expected shape \[3, 3\]"),
    ({"width": 0}, "width: must be a positive integer"),
    ({"background": 2.0}, r"background: values must lie in \[0, 1\]"),
    ({"background": (0.1, 0.2)}, "background: expected a number or 3 numbers"),
])
def test_bad_input_is_named(kwargs, match):
    args = {"vertices": QUAD_V[:3], "faces": QUAD_F[:1], "viewmat": np.eye(4), "K": K, "width": 8, "height": 8}
    with pytest.raises(ValueError, match=match):
        normal_map(**{**args, **kwargs})


def test_body_bad_pose_is_named():
    mesh = _skinned_box()
    view = np.eye(4)
    with pytest.raises(ValueError, match=r"pose: 1 non-finite"):
        body_normal_map(mesh, np.array([[np.nan, 0, 0], [0, 0, 0]]), np.zeros(3), view, K, 8, 8)
    with pytest.raises(ValueError, match=r"pose: expected one frame \[2, 3\]"):
        body_normal_map(mesh, np.zeros((1, 2, 3)), np.zeros((1, 3)), view, K, 8, 8)
