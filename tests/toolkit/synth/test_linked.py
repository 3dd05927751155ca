"""A fitted subject linked to its synthetic truth (toolkit/synth/linked.py): the truth's split and sequences, and
TruthRenderer's truth at the fitted subject's Generator draws: the same images as the synthetic subject's own truth
when the fit is the truth seen from another world and camera."""

import numpy as np
import pytest

pytest.importorskip("torch")
pytest.importorskip("anny")

from trioman.runtime.formats import load_subject, save_subject  # noqa: E402
from trioman.runtime.generator import sample  # noqa: E402
from trioman.toolkit.synth.linked import link_fitted  # noqa: E402
from trioman.toolkit.synth.subject import SynthConfig, TruthRenderer, synthesize_subject  # noqa: E402


@pytest.fixture(scope="module")
def truth(tmp_path_factory):
    root = tmp_path_factory.mktemp("linked")
    return synthesize_subject(SynthConfig(seed=3, size=48, frames=16, coverage=0.5), root / "truth", progress=False)


def refit(truth, out, keep=None, shift=(0.0, 0.0, 0.0), focal=1.0, generator=None):
    """``truth`` as a fit would store it: frames ``keep``, the world moved by ``shift`` (m) and the focal scaled by
    ``focal`` (the camera's frames, so the images, stay the truth's)."""
    keep = list(range(truth.num_frames)) if keep is None else keep
    move = np.eye(4, dtype=np.float32)
    move[:3, 3] = -np.asarray(shift, np.float32)
    K = truth.K[keep].copy()
    K[:, :2, :2] *= focal
    return save_subject(out, body=truth.body, poses=truth.poses[keep], trans=truth.trans[keep] + np.float32(shift), K=K,
                        viewmat=truth.viewmat[keep] @ move, split=["train"] * len(keep), sequence=["video"] * len(keep),
                        images=(truth.image(i) for i in keep), masks=(truth.mask(i) for i in keep), width=truth.width,
                        height=truth.height, body_model=truth.body_model, frame_names=truth.frame_names[keep].tolist(),
                        generator=generator or {"tool": "trioman fit"})


def test_the_linked_subject_takes_the_truths_split_and_sequences(truth, tmp_path):
    keep = [i for i in range(truth.num_frames) if not (i % 3 == 1 and truth.split[i] == "train")]  # frames the fit dropped
    linked = link_fitted(refit(truth, tmp_path / "fit", keep), truth, tmp_path / "linked")
    assert linked.split.tolist() == truth.split[keep].tolist() and linked.sequence.tolist() == truth.sequence[keep].tolist()
    assert np.array_equal(linked.poses_true, truth.poses[keep]) and linked.meta["generator"]["truth"]["frames"] == keep
    assert linked.meta["generator"]["tool"] == "trioman fit"
    np.testing.assert_array_equal(load_subject(tmp_path / "linked").image(3), truth.image(keep[3]))


def test_truth_at_a_draw_of_a_fit_in_another_world_and_camera_is_the_truths_own(truth, tmp_path):
    linked = link_fitted(refit(truth, tmp_path / "fit", shift=(0.4, -0.3, 0.2), focal=0.8), truth, tmp_path / "linked")
    ours, theirs = TruthRenderer(linked), TruthRenderer(truth)
    for i in (0, 5, truth.num_frames - 1):
        mine = sample(linked.body.skeleton, linked.poses[i], linked.trans[i], linked.viewmat[i], seed=i, n=2)
        same = sample(truth.body.skeleton, truth.poses[i], truth.trans[i], truth.viewmat[i], seed=i, n=2)
        for a, b in zip(mine, same):
            assert abs(a.camera.azimuth) > 1e-3  # the camera moved
            got, got_mask = ours.at_draw(i, a, linked.K[i])  # the fit's intrinsics are not the truth's
            want, want_mask = theirs.at_draw(i, b, truth.K[i])
            assert got_mask.sum() > 20
            np.testing.assert_allclose(got_mask, want_mask, atol=1e-3)
            np.testing.assert_allclose(got, want, atol=1e-3)


def test_bad_links_are_named(truth, tmp_path):
    fitted = refit(truth, tmp_path / "fit")
    with pytest.raises(ValueError, match="not a synthetic subject"):
        link_fitted(truth, fitted, tmp_path / "x")
    test = [i for i, s in enumerate(truth.split) if s == "test"]
    lost = truth.sequence[test[0]]
    keep = [i for i in range(truth.num_frames) if truth.sequence[i] != lost]
    with pytest.raises(ValueError, match="no frame of the truth's test sequences"):
        link_fitted(refit(truth, tmp_path / "fit2", keep), truth, tmp_path / "x")
    linked = link_fitted(fitted, truth, tmp_path / "linked")
    meta = dict(linked.meta)
    meta["generator"] = {**meta["generator"], "truth": {**meta["generator"]["truth"], "K": [[1.0]]}}
    with pytest.raises(ValueError, match="generator.truth.K"):
        TruthRenderer(type(linked)(**{**linked.__dict__, "meta": meta}))
    with pytest.raises(ValueError, match="no generator.truth link"):
        TruthRenderer(fitted)
