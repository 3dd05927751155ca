"""Triplets for the Refiner/Examiner: built from a tiny run, sampled within sequences, evaluated against
the nearest-view training frame; frame subsets for baselines."""

import numpy as np
import pytest

pytest.importorskip("torch")
pytest.importorskip("anny")

from tests.toolkit.train.factories import TINY_AVATAR  # noqa: E402
from trioman.runtime.formats import FormatError, load_subject  # noqa: E402
from trioman.toolkit.synth.subject import SynthConfig, synthesize_subject  # noqa: E402
from trioman.toolkit.train.config import TrainConfig  # noqa: E402
from trioman.toolkit.train.data import load_frames  # noqa: E402
from trioman.toolkit.train.loop import train  # noqa: E402
from trioman.toolkit.corpus.triplets import TRIPLETS_VERSION, TripletSet, build_triplets, triplets_version, view_yaw  # noqa: E402


@pytest.fixture(scope="module")
def triplet_file(tmp_path_factory):
    root = tmp_path_factory.mktemp("trip")
    subject = synthesize_subject(SynthConfig(seed=3, size=32, frames=14, texture_size=256), root / "s", progress=False)
    cfg = TrainConfig(iterations=3, checkpoint_every=3, frames="all", avatar=TINY_AVATAR)
    run = train(subject.root, root / "run", cfg, progress=False)
    return build_triplets(run, root / "t.npz", progress=False), subject


def test_triplet_file_contents(triplet_file):
    path, subject = triplet_file
    ts = TripletSet.load([path])
    assert len(ts) == subject.num_frames and ts.gt.shape == (14, 32, 32, 3) and ts.normal.dtype == np.uint8
    np.testing.assert_array_equal(ts.gt[5], np.rint(subject.image(5) * 255).astype(np.uint8))
    fg = ts.mask[0] > 128
    assert fg.any() and np.abs(ts.normal[0][fg].astype(int) - 128).max() > 40  # normals drawn on the body
    assert np.all(ts.normal[0][~fg & (ts.mask[0] == 0)] == 0)


def test_sampling_pairs_frames_of_one_sequence(triplet_file):
    ts = TripletSet.load([triplet_file[0]])
    for i in range(len(ts)):
        p = ts.partners(i, 3)
        assert np.all(np.abs(p - i) <= 3) and i not in p and np.all(ts.group[p] == ts.group[i])
    b = ts.sample(np.random.default_rng(0), 6, k_max=2, split="train")
    assert b.gt.shape == (6, 32, 32, 3) and b.gt.dtype == np.float32 and 0 <= b.gt.min() and b.gt.max() <= 1
    a = ts.sample(np.random.default_rng(0), 6, k_max=2, split="train")
    np.testing.assert_array_equal(a.reference, b.reference)
    ev = ts.evaluation("test")
    assert len(ev.gt) == int((ts.split == "test").sum())
    near, again = ts.nearby("test", k_max=2, seed=1), ts.nearby("test", k_max=2, seed=1)
    test = np.nonzero(ts.split == "test")[0]
    np.testing.assert_array_equal(near.gt, ts.gt[test] * np.float32(1 / 255))  # every test frame, in order
    np.testing.assert_array_equal(near.reference, again.reference)  # seeded
    for j, i in enumerate(test):  # each reference is a partner T+k of its frame (or itself if it has none)
        p = ts.partners(int(i), 2)
        ok = [k for k in (p if len(p) else [i]) if np.array_equal(ts.gt[k] * np.float32(1 / 255), near.reference[j])]
        assert ok


def test_nearest_view_and_yaw():
    # a body facing the camera has yaw 0; turned by 90 degrees about z, +-pi/2
    from trioman.runtime.cameras import orbit_viewmat

    vm = orbit_viewmat(np.zeros(3), 0.0, 0.0, 3.0)[None]
    assert abs(view_yaw(np.zeros((1, 3)), vm)[0]) < 1e-6
    assert abs(abs(view_yaw(np.array([[0, 0, np.pi / 2]]), vm)[0]) - np.pi / 2) < 1e-6
    assert abs(abs(view_yaw(np.array([[0, 0, np.pi]]), vm)[0]) - np.pi) < 1e-6


def test_frame_subset_and_bad_files(triplet_file, tmp_path):
    subject = load_subject(triplet_file[1].root)
    assert len(load_frames(subject, None, stride=3)) == len(range(0, 14, 3))
    with pytest.raises(ValueError, match="frames: expected 'train' or 'all'"):
        TrainConfig(frames="some")
    bad = tmp_path / "bad.npz"
    np.savez(bad, gt=np.zeros((1, 2, 2, 3), np.uint8))
    with pytest.raises(FormatError, match="meta: missing array"):
        TripletSet.load([bad])


def test_aligned_references_come_from_other_training_frames(triplet_file):
    """Every frame's aligned reference: an own source frame T+k of its sequence in the train split
    (0 < |k| <= ALIGN_K), never T; carried pixels only on the body, and close to T's own image there
    (the subject's texture is painted on the body, so carried real pixels are near the truth)."""
    from trioman.runtime.formats.common import load_npz
    from trioman.toolkit.corpus.triplets import ALIGN_K

    path, subject = triplet_file
    a = load_npz(path)
    src, valid = a["aligned_from"], a["valid"] > 127
    split, seq = np.asarray(subject.split), np.asarray(subject.sequence)
    for i, j in enumerate(src):
        assert j != i and split[j] == "train"
        if any(split[k] == "train" and seq[k] == seq[i] and k != i for k in range(max(0, i - ALIGN_K), i + ALIGN_K + 1)
               if k < len(split)):
            assert 0 < abs(int(j) - i) <= ALIGN_K and seq[j] == seq[i]
    assert valid.mean(axis=(1, 2)).min() > 0.02  # some body pixels carried in every frame
    assert np.all(a["aligned"][~valid] == 0) and np.all((a["mask"][valid] > 0))
    gt, aligned = a["gt"].astype(np.float64), a["aligned"].astype(np.float64)
    err_aligned = np.abs(aligned - gt)[valid].mean()
    err_coarse = np.abs(a["coarse"].astype(np.float64) - gt)[valid].mean()
    assert err_aligned < err_coarse  # a 3-step avatar renders far from the truth; carried pixels do not
    ts = TripletSet.load([path])
    fused = ts.take(np.arange(len(ts)), np.arange(len(ts))).aligned
    np.testing.assert_array_equal(fused[~valid], ts.coarse[~valid] * np.float32(1 / 255))
    np.testing.assert_array_equal(fused[valid], a["aligned"][valid] * np.float32(1 / 255))
    assert ts.resized(16).aligned.shape == (len(ts), 16, 16, 3)


def test_triplets_without_aligned_references_still_load(triplet_file, tmp_path):
    """A version-1 file (no aligned arrays) loads for the paper's conditions; warp batches say what is missing."""
    import torch

    from trioman.runtime.formats.common import load_npz
    from trioman.toolkit.corpus.training import refiner_batch
    from trioman.toolkit.refiner import refiner_inputs

    a = load_npz(triplet_file[0])
    old = tmp_path / "v1.npz"
    np.savez(old, **{k: v for k, v in a.items() if k not in ("aligned", "valid", "aligned_from")})
    ts = TripletSet.load([old])
    assert ts.aligned is None and triplets_version(triplet_file[0]) == TRIPLETS_VERSION == 2
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(FormatError, match="junk.npz: meta: not a readable triplet file"):
        triplets_version(tmp_path / "junk.npz")
    batch = refiner_batch(ts.sample(np.random.default_rng(0), 2))
    assert len(refiner_inputs(batch, "tex+geo")) == 3 and isinstance(batch.coarse, torch.Tensor)
    with pytest.raises(ValueError, match="aligned: required with conditions='warp'"):
        refiner_inputs(batch, "warp")


def test_draw_triplets_hold_the_truth_at_generator_draws(triplet_file, tmp_path):
    """Triplets at Generator draws: the truth there (the subject's own renderer), the avatar's render, the aligned
    reference from the draw's own source frame; every row a training row naming its source frame."""
    from trioman.runtime.formats.common import load_npz
    from trioman.toolkit.corpus.triplets import build_draw_triplets

    path, subject = triplet_file
    run = path.parent / "run"
    out = build_draw_triplets(run, tmp_path / "d.npz", draws=2, seed=1, progress=False)
    a = load_npz(out)
    train = subject.indices("train")
    assert len(a["gt"]) == 2 * len(train) and set(a["split"]) == {"train"} and triplets_version(out) == TRIPLETS_VERSION
    np.testing.assert_array_equal(a["frame"], np.repeat(train, 2))
    np.testing.assert_array_equal(a["aligned_from"], a["frame"])
    valid, body = a["valid"] > 127, a["mask"] > 127
    assert valid.mean() > 0.02 and np.all(a["aligned"][~valid] == 0)
    gt = a["gt"].astype(np.float64)
    # the draw's own frame carried to it lies closer to the truth than a 3-step avatar's render
    assert np.abs(a["aligned"].astype(np.float64) - gt)[valid].mean() < np.abs(a["coarse"].astype(np.float64) - gt)[valid].mean()
    assert not np.array_equal(a["gt"][0], a["gt"][1])  # two draws of one frame differ
    assert body.any() and TripletSet.load([out]).aligned is not None
    from trioman.cli import main

    assert main(["triplets", str(run), "--out", str(tmp_path / "e.npz"), "--draws", "2", "--seed", "1", "--quiet"]) == 0
    np.testing.assert_array_equal(load_npz(tmp_path / "e.npz")["gt"], a["gt"])  # seeded
    assert main(["triplets", str(run), "--out", str(tmp_path / "f.npz"), "--draws", "0"]) == 1
    assert not (tmp_path / "f.npz").exists()
