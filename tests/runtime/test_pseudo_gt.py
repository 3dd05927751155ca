"""The shared augmentation step: what each kind of pseudo-GT holds, its mask and its per-pixel weights."""

import numpy as np
import pytest

from tests.runtime.painted_box import FRONT, K, MESH, POSE, SIZE, TRANS, paint, views
from trioman.runtime.aligned import AlignConfig, Aligner
from trioman.runtime.generator import GeneratorConfig, sample
from trioman.runtime.pseudo_gt import PseudoConfig, Source, make_pseudo_frames, needs_aligner

BG = np.array([0.2, 0.4, 0.6], np.float32)


def junk_render(c):
    """A coarse render: the truth, 0.1 darker, plus a blob of junk well off the body (alpha 1 there)."""
    rgb, mask = paint(c.pose, c.trans, c.viewmat)
    alpha = mask.copy()
    alpha[2:8, 2:8] = 1.0
    out = np.where(alpha[..., None] > 0, np.clip(rgb - 0.1, 0, 1), BG)
    out[2:8, 2:8] = [1.0, 0.0, 1.0]
    return out.astype(np.float32), alpha


def draws(n=2, seed=0):
    return sample(MESH.skeleton, POSE, TRANS, FRONT, seed, n, GeneratorConfig(azimuth_sigma=0.2))


def source():
    rgb, mask = paint(POSE, TRANS, FRONT)
    return Source(0, (rgb + (1 - mask)[..., None] * BG).astype(np.float32), K, BG)


def aligner():
    return Aligner(MESH, views([FRONT]), AlignConfig(sources=1))


def test_coarse_with_the_render_alpha_is_the_render_itself():
    cands = draws(1)
    made = make_pseudo_frames(cands, source(), junk_render, PseudoConfig("coarse", mask="alpha"))
    rgb, alpha = junk_render(cands[0])
    np.testing.assert_allclose(made.images[0], rgb, atol=1e-6)
    np.testing.assert_array_equal(made.masks[0], alpha)
    assert made.kept == [0] and np.all(made.weights == 1) and made.coverage == []


def test_the_carried_mask_drops_the_junk_off_the_body():
    cands = draws(1)
    made = make_pseudo_frames(cands, source(), junk_render, PseudoConfig("coarse"), aligner=aligner())
    assert made.masks[0][2:8, 2:8].max() == 0.0  # off the body: the background, not the junk
    np.testing.assert_allclose(made.images[0][2:8, 2:8], np.broadcast_to(BG, (6, 6, 3)), atol=1e-6)
    _, body = paint(cands[0].pose, cands[0].trans, cands[0].viewmat)
    np.testing.assert_array_equal(made.masks[0], body)  # the box has no clothing beyond its body


def test_aligned_carries_real_pixels_and_weights_only_what_is_known():
    cands = draws(2, seed=3)
    made = make_pseudo_frames(cands, source(), junk_render, PseudoConfig("aligned", unknown_weight=0.25), aligner=aligner())
    for k, c in enumerate(cands):
        a = aligner().align(0, c.pose, c.trans, c.viewmat, K, junk_render(c)[0])
        truth, _ = paint(c.pose, c.trans, c.viewmat)
        inner = a.valid
        assert inner.sum() > 0.5 * a.body.sum()
        # the carried pixels are the truth's colours (the render is 0.1 darker)
        assert np.abs(made.images[k][inner] - truth[inner]).mean() < 0.5 * np.abs(junk_render(c)[0][inner] - truth[inner]).mean()
        np.testing.assert_array_equal(made.weights[k][a.body & ~a.valid], 0.25)
        np.testing.assert_array_equal(made.weights[k][~(a.body & ~a.valid)], 1.0)
        assert made.coverage[k] == pytest.approx(a.coverage)


def test_truth_takes_the_subjects_own_renderer():
    cands = draws(1)
    made = make_pseudo_frames(cands, source(), junk_render, PseudoConfig("truth"), aligner=aligner(),
                              truth=lambda c, K_: paint(c.pose, c.trans, c.viewmat))
    rgb, mask = paint(cands[0].pose, cands[0].trans, cands[0].viewmat)
    np.testing.assert_allclose(made.images[0], rgb + (1 - mask)[..., None] * BG, atol=1e-6)
    np.testing.assert_array_equal(made.masks[0], mask)


def test_truth_seen_supervises_the_truth_only_where_real_pixels_were_carried():
    cands = draws(2, seed=3)
    made = make_pseudo_frames(cands, source(), junk_render, PseudoConfig("truth_seen", unknown_weight=0.25),
                              aligner=aligner(), truth=lambda c, K_: paint(c.pose, c.trans, c.viewmat))
    for k, c in enumerate(cands):
        rgb, mask = paint(c.pose, c.trans, c.viewmat)
        np.testing.assert_allclose(made.images[k], rgb + (1 - mask)[..., None] * BG, atol=1e-6)  # the truth everywhere
        a = aligner().align(0, c.pose, c.trans, c.viewmat, K, junk_render(c)[0])
        unseen = a.body & ~a.valid
        assert unseen.any() and a.valid.any()  # the draws turn the box: part of it was never seen
        np.testing.assert_array_equal(made.weights[k][unseen], 0.25)
        np.testing.assert_array_equal(made.weights[k][~unseen], 1.0)


class _Brighten:
    conditions = "tex"

    def __init__(self):
        self.seen = None

    def refine(self, coarse, reference=None, normal=None):
        self.seen = (reference, normal)
        return np.clip(coarse + 0.1, 0, 1)


class _PreferSecond:
    def score(self, candidates, reference):
        return np.linspace(0.2, 0.8, len(candidates))


def test_refined_and_examined_feed_the_models_and_pick_the_best():
    ref, src = _Brighten(), source()
    cands = draws(2)
    made = make_pseudo_frames(cands, src, junk_render, PseudoConfig("examined", mask="alpha"), refiner=ref,
                              examiner=_PreferSecond())
    assert made.chosen == 1 and made.kept == [1] and made.scores == pytest.approx([0.2, 0.8])
    np.testing.assert_array_equal(ref.seen[0][0], src.real) and ref.seen[1] is None
    rgb, alpha = junk_render(cands[1])
    want = np.clip(rgb + 0.1, 0, 1) * alpha[..., None] + (1 - alpha)[..., None] * BG
    np.testing.assert_allclose(made.images[1], want, atol=1e-6)
    dropped = make_pseudo_frames(cands, src, junk_render, PseudoConfig("examined", mask="alpha", threshold=0.9),
                                 refiner=ref, examiner=_PreferSecond())
    assert dropped.kept == [] and dropped.chosen == 1


class _Warp(_Brighten):
    conditions = "warp+geo"

    def refine(self, coarse, reference=None, normal=None):
        self.seen = (reference, normal)
        return np.clip(reference + 0.1, 0, 1)


def test_a_warp_refiner_refines_the_aligned_reference():
    """A "warp*" Refiner gets the aligned kind's image (real pixels where carried, the render elsewhere) as its
    reference, and the body's normal map; its output is the pseudo-GT."""
    ref, cands = _Warp(), draws(2, seed=3)
    made = make_pseudo_frames(cands, source(), junk_render, PseudoConfig("refined"), body=MESH, aligner=aligner(),
                              refiner=ref)
    plain = make_pseudo_frames(cands, source(), junk_render, PseudoConfig("aligned", unknown_weight=1.0), aligner=aligner())
    reference, normal = ref.seen
    body = made.masks == 1
    np.testing.assert_allclose(reference[body], plain.images[body], atol=1e-6)
    assert normal.shape == reference.shape and np.abs(normal[body] - 0.5).max() > 0.2  # normals drawn on the body
    np.testing.assert_allclose(made.images[body], np.clip(reference[body] + 0.1, 0, 1), atol=1e-6)
    assert np.all(made.weights == 1) and len(made.coverage) == 2
    with pytest.raises(ValueError, match="'warp\\+geo' Refiner needs an Aligner"):
        make_pseudo_frames(cands, source(), junk_render, PseudoConfig("refined", mask="alpha"), body=MESH, refiner=ref)


def test_keep_carried_takes_the_refiner_only_where_nothing_was_carried():
    """keep_carried: the carried real pixels stay as the aligned kind has them; the rest is the Refiner's."""
    cands = draws(2, seed=3)
    ref = _Brighten()  # a tex Refiner: without keep_carried it needs no Aligner
    made = make_pseudo_frames(cands, source(), junk_render, PseudoConfig("refined", keep_carried=True),
                              aligner=aligner(), refiner=ref)
    plain = make_pseudo_frames(cands, source(), junk_render, PseudoConfig("aligned"), aligner=aligner())
    for k, c in enumerate(cands):
        a = aligner().align(0, c.pose, c.trans, c.viewmat, K, junk_render(c)[0])
        assert a.valid.sum() > 0 and (a.body & ~a.valid).sum() > 0
        np.testing.assert_allclose(made.images[k][a.valid], plain.images[k][a.valid], atol=1e-6)
        fill = a.body & ~a.valid & (made.masks[k] == 1)
        np.testing.assert_allclose(made.images[k][fill], np.clip(junk_render(c)[0][fill] + 0.1, 0, 1), atol=1e-6)
    assert needs_aligner(PseudoConfig("refined", mask="alpha", keep_carried=True), "tex")
    with pytest.raises(ValueError, match="keep_carried: needs kind 'refined' or 'examined'"):
        PseudoConfig("aligned", keep_carried=True)


def test_truth_needs_no_aligner():
    assert not needs_aligner(PseudoConfig("truth")) and needs_aligner(PseudoConfig("coarse"))
    assert needs_aligner(PseudoConfig("truth_seen", mask="alpha"))  # it asks where real pixels were carried
    assert needs_aligner(PseudoConfig("refined", mask="alpha"), "warp") and not needs_aligner(PseudoConfig("refined", mask="alpha"), "tex")


@pytest.mark.parametrize("cfg, kw, match", [
    (PseudoConfig("refined", mask="alpha"), {}, "refiner: kind 'refined' needs a Refiner"),
    (PseudoConfig("truth", mask="alpha"), {}, "truth: kind 'truth' needs"),
    (PseudoConfig("truth_seen"), {}, "truth: kind 'truth_seen' needs"),
    (PseudoConfig("aligned"), {}, "aligner: kind 'aligned'"),
])
def test_missing_parts_are_named(cfg, kw, match):
    with pytest.raises(ValueError, match=match):
        make_pseudo_frames(draws(1), source(), junk_render, cfg, **kw)


@pytest.mark.parametrize("kwargs, field", [({"kind": "magic"}, "kind"), ({"mask": "box"}, "mask"),
                                           ({"unknown_weight": 2.0}, "unknown_weight"),
                                           ({"detail_sigma": float("inf")}, "detail_sigma")])
def test_bad_config_is_named(kwargs, field):
    with pytest.raises(ValueError, match=field):
        PseudoConfig(**kwargs)


def test_timings_name_the_stages_that_ran():
    seconds = {}
    make_pseudo_frames(draws(1), source(), junk_render, PseudoConfig("aligned"), aligner=aligner(), seconds=seconds)
    assert set(seconds) == {"render", "align"} and all(v >= 0 for v in seconds.values())
    assert SIZE == source().real.shape[0]
