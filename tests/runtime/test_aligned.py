"""The geometry-aligned reference against brute force: a colour field painted on a skinned box, rendered
directly at the draw by the mesh rasterizer, is what carrying the source frame's pixels must reproduce."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tests.runtime.painted_box import CENTER, FRONT, K, MESH, POSE, SIZE, TRANS, paint, views
from trioman.runtime.aligned import AlignConfig, Aligner
from trioman.runtime.cameras import orbit_viewmat


def test_the_own_frame_at_its_own_draw_is_reproduced_exactly():
    a = Aligner(MESH, views([FRONT]), AlignConfig(sources=1)).align(0, POSE, TRANS, FRONT, K)
    rgb, mask = paint(POSE, TRANS, FRONT)
    assert a.coverage > 0.95 and np.array_equal(a.body, mask > 0)
    np.testing.assert_allclose(a.rgb[a.valid], rgb[a.valid], atol=1e-5)


@pytest.mark.parametrize("azimuth, bend", [(0.3, 0.0), (-0.25, 0.3)])
def test_a_nearby_draw_matches_the_colour_field_painted_there(azimuth, bend):
    """Another camera and a bent spine: carried pixels equal the field rendered directly, up to bilinear resampling."""
    pose = np.array([[0.0, 0.0, 0.0], [bend, 0.0, 0.0]])
    draw = orbit_viewmat(CENTER, azimuth, 0.15, 2.8)
    a = Aligner(MESH, views([FRONT]), AlignConfig(sources=1)).align(0, pose, TRANS, draw, K)
    truth, _ = paint(pose, TRANS, draw)
    source, _ = paint(POSE, TRANS, FRONT)
    assert a.coverage > 0.6
    carried = np.abs(a.rgb - truth)[a.valid].mean()
    unaligned = np.abs(source - truth)[a.valid].mean()
    assert carried < 0.25 * unaligned, (carried, unaligned)  # what is left is bilinear resampling of point samples


def test_surfaces_the_source_does_not_see_are_not_carried():
    back = orbit_viewmat(CENTER, np.pi, 0.1, 3.0)
    assert Aligner(MESH, views([FRONT]), AlignConfig(sources=1)).align(0, POSE, TRANS, back, K).coverage < 0.05
    # a second source frame behind the box fills it, chosen by viewing direction
    al = Aligner(MESH, views([FRONT, orbit_viewmat(CENTER, np.pi + 0.1, 0.1, 3.0)]), AlignConfig(sources=2))
    assert al.sources_for(0, POSE, TRANS, back) == [0, 1]
    assert al.align(0, POSE, TRANS, back, K).coverage > 0.9


def test_pixels_outside_the_source_mask_are_not_carried():
    empty = [np.zeros((SIZE, SIZE), np.float32)]
    a = Aligner(MESH, views([FRONT], masks=empty), AlignConfig(sources=1)).align(0, POSE, TRANS, FRONT, K)
    assert a.coverage == 0.0 and not a.valid.any() and a.body.any()


def test_the_silhouette_is_the_body_plus_the_source_mask_beyond_the_body():
    draw = orbit_viewmat(CENTER, 0.2, 0.1, 3.0)
    _, body_mask = paint(POSE, TRANS, FRONT)
    plain = Aligner(MESH, views([FRONT]), AlignConfig(sources=1)).align(0, POSE, TRANS, draw, K)
    np.testing.assert_array_equal(plain.silhouette, plain.body.astype(np.float32))  # clothing painted on
    skirt = body_mask.copy()
    cols = np.flatnonzero(body_mask[40:50].any(0))
    skirt[40:50, cols.min() - 4: cols.max() + 5] = 1.0  # the person reaches 4 px beyond the body's silhouette
    wide = Aligner(MESH, views([FRONT], masks=[skirt]), AlignConfig(sources=1)).align(0, POSE, TRANS, draw, K)
    extra = (wide.silhouette > 0.5) & ~wide.body
    assert extra.sum() > 0.5 * (skirt > body_mask).sum()  # carried along
    assert not extra[:30].any()  # and only near where it was
    far = Aligner(MESH, views([FRONT], masks=[skirt]), AlignConfig(sources=1, band=0.01)).align(0, POSE, TRANS, draw, K)
    assert ((far.silhouette > 0.5) & ~far.body).sum() < extra.sum()


def test_flow_realigns_the_carried_pixels_to_the_render():
    """A render displaced by 2 px (a fitted pose off by that much): the carried pixels follow it."""
    rgb, mask = paint(POSE, TRANS, FRONT)
    src = views([FRONT])
    shifted = np.roll(rgb, 2, axis=1) + 0.3 * (1 - np.roll(mask, 2, axis=1))[..., None]
    a = Aligner(MESH, src, AlignConfig(sources=1)).align(0, POSE, TRANS, FRONT, K, coarse=shifted)
    inner = a.valid & (np.roll(mask, 2, axis=1) > 0)
    assert inner.sum() > 0.5 * mask.sum()
    err_aligned = np.abs(a.rgb - shifted)[inner].mean()
    err_unaligned = np.abs(rgb - shifted)[inner].mean()
    assert err_aligned < 0.5 * err_unaligned, (err_aligned, err_unaligned)
    strict = Aligner(MESH, src, AlignConfig(sources=1, max_flow=0.5 / SIZE)).align(0, POSE, TRANS, FRONT, K, coarse=shifted)
    assert strict.coverage < 0.5 * a.coverage  # flows longer than the limit are dropped


@pytest.mark.parametrize("kwargs, field", [({"sources": 0}, "sources"), ({"depth_tolerance": 0.0}, "depth_tolerance"),
                                           ({"min_cosine": 1.0}, "min_cosine"), ({"max_flow": float("nan")}, "max_flow"),
                                           ({"band": -1.0}, "band")])
def test_bad_config_is_named(kwargs, field):
    with pytest.raises(ValueError, match=field):
        AlignConfig(**kwargs)


def test_degenerate_draws_give_finite_output():
    """A camera looking away (no body pixel) and a zero-size source mask: empty, finite, no error."""
    away = orbit_viewmat(CENTER + [0, 0, 50.0], 0.0, 0.1, 3.0)
    a = Aligner(MESH, views([FRONT]), AlignConfig(sources=1)).align(0, POSE, TRANS, away, K, coarse=np.zeros((SIZE, SIZE, 3)))
    assert not a.body.any() and a.coverage == 0.0 and np.isfinite(a.rgb).all() and not a.silhouette.any()


@settings(max_examples=25, deadline=None)
@given(azimuth=st.floats(-np.pi, np.pi), elevation=st.floats(-1.5, 1.5), distance=st.floats(0.05, 1e3),
       bend=st.floats(-np.pi, np.pi), shift=st.floats(-50.0, 50.0))
def test_any_draw_gives_finite_consistent_output(azimuth, elevation, distance, bend, shift):
    """Extreme cameras (inside the box, far away, at the poles) and joint angles: finite, valid only on the body."""
    pose = np.array([[0.0, 0.0, 0.0], [bend, 0.0, 0.0]])
    draw = orbit_viewmat(CENTER, azimuth, elevation, distance)
    coarse = np.clip(np.full((SIZE, SIZE, 3), 0.5) + 0.01 * shift, 0, 1)
    a = Aligner(MESH, views([FRONT]), AlignConfig(sources=2)).align(0, pose, np.array([0.0, 0.0, 0.0]), draw, K, coarse)
    assert np.isfinite(a.rgb).all() and a.rgb.min() >= 0 and a.rgb.max() <= 1
    assert not (a.valid & ~a.body).any() and 0.0 <= a.coverage <= 1.0
    assert np.isfinite(a.silhouette).all() and a.silhouette.min() >= 0 and a.silhouette.max() <= 1
