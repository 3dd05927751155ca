"""The subject format: save/load round trip, validation errors, atomic saves, `trioman inspect`."""

from __future__ import annotations

import importlib.util
import json
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from tests.runtime.factories import H, N, W, make_fields, make_images
from trioman.runtime.formats import FormatError, Subject, load_subject, save_subject
from trioman.runtime.image_io import write_png


@pytest.fixture
def subject_dir(tmp_path) -> Path:
    images, masks = make_images()
    path = tmp_path / "subj"
    save_subject(path, images=images, masks=masks, **make_fields())
    return path


# ------------------------------------------------------------------------------------------------
# round trip


def test_round_trip(tmp_path):
    fields = make_fields()
    images, masks = make_images()
    path = tmp_path / "a" / "subj"  # parent folders are created
    saved = save_subject(path, images=iter(images), masks=(m for m in masks), **fields)
    s = load_subject(path)
    assert isinstance(s, Subject) and isinstance(saved, Subject)
    assert s.num_frames == N and s.width == W and s.height == H and s.num_joints == 3
    for key in ("poses", "trans", "K", "viewmat", "poses_true"):
        got = getattr(s, key)
        assert got.dtype == np.float32
        np.testing.assert_array_equal(got, np.asarray(fields[key], np.float32))
        np.testing.assert_array_equal(getattr(saved, key), got)
    assert s.split.tolist() == fields["split"]
    assert s.sequence.tolist() == fields["sequence"]
    assert s.frame_names.tolist() == [f"{i:06d}" for i in range(N)]
    assert s.sequences == ("walk", "dance")
    assert s.meta["generator"] == {"tool": "pytest", "seed": 7, "pose_noise_sigma": 0.05}
    assert s.meta == saved.meta
    assert s.body_model == "test-chain"
    np.testing.assert_array_equal(s.background, [1, 1, 1])
    body_a, body_b = s.body.to_arrays(), fields["body"].to_arrays()
    assert body_a.keys() == body_b.keys()
    for k in body_a:
        np.testing.assert_array_equal(body_a[k], body_b[k])
    for i in range(N):
        img, mask = s.image(i), s.mask(i)
        assert img.shape == (H, W, 3) and img.dtype == np.float32
        assert mask.shape == (H, W) and mask.dtype == np.float32
        np.testing.assert_array_equal(img, np.rint(images[i] * 255) / np.float32(255))
        np.testing.assert_allclose(mask, np.rint(masks[i] * 255) / 255, atol=1e-7)
    np.testing.assert_array_equal(s.indices("train"), [0, 1, 2])
    np.testing.assert_array_equal(s.indices("test"), [3, 4])
    np.testing.assert_array_equal(s.indices(sequence="dance"), [3, 4])
    np.testing.assert_array_equal(s.indices("train", sequence="dance"), [])
    with pytest.raises(ValueError, match="split"):
        s.indices("val")
    with pytest.raises(IndexError, match="frame index"):
        s.image(N)
    # arrays are read-only; the posed mesh runs through the body
    with pytest.raises(ValueError):
        s.poses[0, 0, 0] = 1.0
    assert s.posed_vertices(0).shape == (6, 3)
    np.testing.assert_allclose(s.posed_vertices(1, true_pose=True), s.body.pose(s.poses_true[1], s.trans[1]))


def test_optional_poses_true_and_custom_names(tmp_path):
    fields = make_fields()
    fields["poses_true"] = None
    fields["frame_names"] = [f"f{i}" for i in range(N)]
    images, masks = make_images()
    masks = [m > 0.5 for m in masks]  # bool masks are accepted
    save_subject(tmp_path / "s", images=images, masks=masks, **fields)
    s = load_subject(tmp_path / "s")
    assert s.poses_true is None
    assert (tmp_path / "s" / "images" / "f3.png").is_file()
    assert set(np.unique(s.mask(0)).tolist()) <= {0.0, 1.0}
    with np.load(tmp_path / "s" / "frames.npz", allow_pickle=False) as z:
        assert "poses_true" not in z.files


def test_save_pulls_image_and_mask_together(tmp_path):
    """One render pass split with itertools.tee buffers a single frame: image i and mask i alternate."""
    images, masks = make_images()
    order = []

    def stream(kind, items):
        for i, x in enumerate(items):
            order.append((kind, i))
            yield x

    save_subject(tmp_path / "s", images=stream("image", images), masks=stream("mask", masks), **make_fields())
    assert order == [(k, i) for i in range(N) for k in ("image", "mask")]


def test_check_images_false_skips_image_files(subject_dir):
    (subject_dir / "images" / "000002.png").unlink()
    s = load_subject(subject_dir, check_images=False)
    assert s.num_frames == N
    with pytest.raises(FormatError, match=r"000002\.png: missing file"):
        s.image(2)


# ------------------------------------------------------------------------------------------------
# save: overwrite and atomicity


def test_save_refuses_to_overwrite(subject_dir):
    images, masks = make_images(seed=5)
    with pytest.raises(FileExistsError, match="not empty \\(give `overwrite` to replace it\\)"):
        save_subject(subject_dir, images=images, masks=masks, **make_fields())
    assert load_subject(subject_dir).image(0).shape == (H, W, 3)  # untouched
    save_subject(subject_dir, images=images, masks=masks, overwrite=True, **make_fields())
    np.testing.assert_array_equal(load_subject(subject_dir).image(0), np.rint(images[0] * 255) / np.float32(255))
    assert sorted(p.name for p in subject_dir.parent.iterdir()) == ["subj"]


def test_overwrite_never_replaces_a_folder_that_is_not_a_subject(subject_dir, tmp_path):
    # A raw capture (no subject.json), a folder holding a thesis, a subject with a file of the user's: all kept.
    capture = tmp_path / "capture"
    for name in ("cameras.txt", "frames/000000.png", "smplx_fits/000000.json"):
        (capture / name).parent.mkdir(parents=True, exist_ok=True)
        (capture / name).write_text("raw")
    (subject_dir / "notes.txt").write_text("mine")
    images, masks = make_images(seed=5)
    for out, foreign in ((capture, capture / "cameras.txt"), (subject_dir, subject_dir / "notes.txt")):
        with pytest.raises(FileExistsError, match=rf"^overwrite: {foreign} was not written by trioman"):
            save_subject(out, images=images, masks=masks, overwrite=True, **make_fields())
    assert (capture / "frames" / "000000.png").read_text() == "raw" and (subject_dir / "notes.txt").is_file()
    (subject_dir / "notes.txt").unlink()
    (subject_dir / "contact_sheet.png").write_bytes(b"png")  # trioman synth's: part of a subject folder
    with pytest.raises(ValueError, match=rf"{capture / 'subject'}: lies inside the input {capture}"):
        save_subject(capture / "subject", images=images, masks=masks, inputs=[capture], **make_fields())
    save_subject(subject_dir, images=images, masks=masks, overwrite=True, **make_fields())
    assert not (capture / "subject").exists() and load_subject(subject_dir).num_frames == N


def test_save_into_existing_empty_folder(tmp_path):
    (tmp_path / "empty").mkdir()
    images, masks = make_images()
    save_subject(tmp_path / "empty", images=images, masks=masks, **make_fields())
    assert load_subject(tmp_path / "empty").num_frames == N


def test_save_interrupted_leaves_nothing(tmp_path):
    images, masks = make_images()

    def broken():
        yield images[0]
        yield images[1]
        raise RuntimeError("renderer crashed")

    with pytest.raises(RuntimeError, match="renderer crashed"):
        save_subject(tmp_path / "subj", images=broken(), masks=masks, **make_fields())
    assert list(tmp_path.iterdir()) == []


def test_save_interrupted_overwrite_keeps_old(subject_dir):
    before = load_subject(subject_dir).image(0)

    def broken():
        yield np.zeros((H, W, 3), np.float32)
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        save_subject(subject_dir, images=broken(), masks=make_images()[1], overwrite=True, **make_fields())
    assert sorted(p.name for p in subject_dir.parent.iterdir()) == ["subj"]
    np.testing.assert_array_equal(load_subject(subject_dir).image(0), before)


@pytest.mark.parametrize(
    "change, match",
    [
        (lambda f, im, m: im.pop(), r"save_subject: images: got 4 images for 5 frames"),
        (lambda f, im, m: m.append(m[0]), r"save_subject: masks: got more masks than the 5 frames"),
        (lambda f, im, m: im.__setitem__(2, im[2][:, :8]), r"save_subject: images\[2\] \(frame '000002'\): expected shape \[12, 16, 3\]"),
        (lambda f, im, m: im.__setitem__(1, im[1] * np.nan), r"images\[1\].*non-finite"),
        (lambda f, im, m: f.__setitem__("split", ["train", "val"] * 2 + ["test"]), r"save_subject: split: .*'val'"),
        (lambda f, im, m: f.__setitem__("width", 0), r"save_subject: width: expected a positive integer, got 0"),
        (lambda f, im, m: f.__setitem__("background", (0, "x", 1)), r"save_subject: background: expected \[r, g, b\]"),
        (lambda f, im, m: f.__setitem__("phenotype", {"age": None}), r"save_subject: phenotype\.age: expected a finite number, got None"),
        (lambda f, im, m: f.__setitem__("K", f["K"] * 0), r"save_subject: K: non-positive focal length in frame 0"),
        (lambda f, im, m: f.__setitem__("generator", {"x": object()}), r"save_subject: generator: object is not JSON"),
        (lambda f, im, m: f.__setitem__("poses", f["poses"][:, :2]), r"save_subject: poses: 2 joints per frame, but body.npz has 3"),
    ],
)
def test_save_rejects_bad_input(tmp_path, change, match):
    fields = make_fields()
    images, masks = make_images()
    change(fields, images, masks)
    with pytest.raises(FormatError, match=match):
        save_subject(tmp_path / "subj", images=images, masks=masks, **fields)
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------------------------------------------------
# load: one test per validation error


def rewrite_json(path: Path, **changes) -> None:
    meta = json.loads((path / "subject.json").read_text())
    for k, v in changes.items():
        if v is ...:
            del meta[k]
        else:
            meta[k] = v
    (path / "subject.json").write_text(json.dumps(meta))


def rewrite_frames(path: Path, **changes) -> None:
    with np.load(path / "frames.npz", allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    for k, v in changes.items():
        if v is ...:
            del arrays[k]
        else:
            arrays[k] = v(arrays[k]) if callable(v) else v
    np.savez(path / "frames.npz", **arrays)


def test_missing_folder(tmp_path):
    with pytest.raises(FormatError, match=r"nope: subject folder not found"):
        load_subject(tmp_path / "nope")


def test_path_is_a_file(tmp_path):
    (tmp_path / "f").write_text("x")
    with pytest.raises(FormatError, match=r"f: not a folder"):
        load_subject(tmp_path / "f")


@pytest.mark.parametrize("name", ["subject.json", "body.npz", "frames.npz"])
def test_missing_file(subject_dir, name):
    (subject_dir / name).unlink()
    with pytest.raises(FormatError, match=rf"{name}: missing file"):
        load_subject(subject_dir)


def test_not_a_subject(subject_dir):
    rewrite_json(subject_dir, format="something-else")
    with pytest.raises(FormatError, match=r"subject\.json: format: expected 'trioman-subject', got 'something-else': not a TrioMan subject"):
        load_subject(subject_dir)


def test_unknown_version(subject_dir):
    rewrite_json(subject_dir, version=2)
    with pytest.raises(FormatError, match=r"subject\.json: version: unknown version 2 \(this trioman reads version 1\)"):
        load_subject(subject_dir)


@pytest.mark.parametrize(
    "changes, match",
    [
        (dict(version="1"), r"version: expected an integer, got '1'"),
        (dict(body_model=...), r"body_model: missing field"),
        (dict(units="cm"), r"units: expected 'm' \(metres\), got 'cm'"),
        (dict(up_axis="y"), r"up_axis: expected 'z', got 'y'"),
        (dict(width=-4), r"width: expected a positive integer, got -4"),
        (dict(height=20000), r"height: 20000 pixels, more than the 8192 a subject may have"),  # issue 41, D11
        (dict(height=12.0), r"height: expected a positive integer, got 12.0"),
        (dict(background=[0, 0, 2]), r"background: expected \[r, g, b\] with values in \[0, 1\], got \[0, 0, 2\]"),
        (dict(phenotype={"height": "tall"}), r"phenotype\.height: expected a finite number, got 'tall'"),
        (dict(generator=[]), r"generator: expected an object, got list"),
        (dict(sequences=["walk", "walk"]), r"sequences: duplicate name\(s\) \['walk'\]"),
    ],
)
def test_bad_meta_fields(subject_dir, changes, match):
    rewrite_json(subject_dir, **changes)
    with pytest.raises(FormatError, match=r"subject\.json: " + match):
        load_subject(subject_dir)


def test_malformed_json(subject_dir):
    (subject_dir / "subject.json").write_text('{"format": "trioman-subject", ')
    with pytest.raises(FormatError, match=r"subject\.json: malformed JSON: .*line 1"):
        load_subject(subject_dir)


def test_json_nan_rejected(subject_dir):
    text = (subject_dir / "subject.json").read_text().replace('"height": 0.5', '"height": NaN')
    (subject_dir / "subject.json").write_text(text)
    with pytest.raises(FormatError, match=r"subject\.json: malformed JSON: NaN is not valid JSON"):
        load_subject(subject_dir)


def test_json_not_an_object(subject_dir):
    (subject_dir / "subject.json").write_text("[1, 2]")
    with pytest.raises(FormatError, match=r"subject\.json: expected a JSON object, got list"):
        load_subject(subject_dir)


def test_num_frames_mismatch(subject_dir):
    rewrite_json(subject_dir, num_frames=6)
    with pytest.raises(FormatError, match=r"frames\.npz: poses: 5 frames, but subject\.json num_frames is 6"):
        load_subject(subject_dir)


def test_array_count_mismatch(subject_dir):
    rewrite_frames(subject_dir, trans=lambda a: a[:4])
    with pytest.raises(FormatError, match=r"frames\.npz: trans: 4 frames, but subject\.json num_frames is 5"):
        load_subject(subject_dir)


def test_string_count_mismatch(subject_dir):
    rewrite_frames(subject_dir, frame_names=lambda a: a[:3])
    with pytest.raises(FormatError, match=r"frames\.npz: frame_names: 3 frames, but subject\.json num_frames is 5"):
        load_subject(subject_dir)


def test_missing_array(subject_dir):
    rewrite_frames(subject_dir, viewmat=...)
    with pytest.raises(FormatError, match=r"frames\.npz: viewmat: missing array \(has: \["):
        load_subject(subject_dir)


@pytest.mark.parametrize(
    "key, value, match",
    [
        ("trans", lambda a: a[:, :2], r"trans: expected shape \[N, 3\], got \[5, 2\]"),
        ("K", lambda a: a[:, :2], r"K: expected shape \[N, 3, 3\], got \[5, 2, 3\]"),
        ("viewmat", lambda a: a[:, :3], r"viewmat: expected shape \[N, 4, 4\], got \[5, 3, 4\]"),
        ("poses", lambda a: a.reshape(5, 9), r"poses: expected shape \[N, 3, 3\], got \[5, 9\]"),
        ("poses_true", lambda a: a[:, :, :2], r"poses_true: expected shape \[N, 3, 3\], got \[5, 3, 2\]"),
        ("split", lambda a: a.reshape(5, 1), r"split: expected shape \[N\] = \[5\], got \[5, 1\]"),
        ("sequence", lambda a: np.zeros(5), r"sequence: expected a unicode string array, got dtype float64"),
        ("trans", lambda a: a.astype(np.str_), r"trans: expected a float array, got dtype <U"),
    ],
)
def test_wrong_shape_or_dtype(subject_dir, key, value, match):
    rewrite_frames(subject_dir, **{key: value})
    with pytest.raises(FormatError, match=r"frames\.npz: " + match):
        load_subject(subject_dir)


@pytest.mark.parametrize("key", ["poses", "trans", "K", "viewmat", "poses_true"])
@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_non_finite(subject_dir, key, bad):
    def poison(a):
        a = a.copy()
        a[3].flat[0] = bad
        return a

    rewrite_frames(subject_dir, **{key: poison})
    with pytest.raises(FormatError, match=rf"frames\.npz: {key}: 1 non-finite value\(s\) \(NaN/Inf\), first in frame 3"):
        load_subject(subject_dir)


def test_joint_count_mismatch(subject_dir):
    rewrite_frames(subject_dir, poses=lambda a: np.concatenate([a, a[:, :1]], axis=1))
    with pytest.raises(FormatError, match=r"frames\.npz: poses: 4 joints per frame, but body\.npz has 3 joints"):
        load_subject(subject_dir)


def test_bad_split_values(subject_dir):
    rewrite_frames(subject_dir, split=np.array(["train", "val", "train", "test", "valid"]))
    with pytest.raises(FormatError, match=r"frames\.npz: split: values must be 'train' or 'test', got \['val', 'valid'\] \(2 frames\)"):
        load_subject(subject_dir)


def test_sequence_not_listed(subject_dir):
    rewrite_frames(subject_dir, sequence=np.array(["walk", "walk", "run", "dance", "dance"]))
    with pytest.raises(FormatError, match=r"frames\.npz: sequence: name\(s\) \['run'\] not listed"):
        load_subject(subject_dir)


def test_non_orthonormal_viewmat(subject_dir):
    def scale(a):
        a = a.copy()
        a[2, :3, :3] *= 1.1
        return a

    rewrite_frames(subject_dir, viewmat=scale)
    with pytest.raises(FormatError, match=r"frames\.npz: viewmat: frame 2: rotation is not orthonormal"):
        load_subject(subject_dir)


def test_reflection_viewmat(subject_dir):
    def mirror(a):
        a = a.copy()
        a[1, 0, :3] *= -1
        return a

    rewrite_frames(subject_dir, viewmat=mirror)
    with pytest.raises(FormatError, match=r"viewmat: frame 1: .*det = -1"):
        load_subject(subject_dir)


def test_viewmat_last_row(subject_dir):
    def bottom(a):
        a = a.copy()
        a[0, 3] = [0, 0, 1, 1]
        return a

    rewrite_frames(subject_dir, viewmat=bottom)
    with pytest.raises(FormatError, match=r"frames\.npz: viewmat: frame 0: last row must be \[0, 0, 0, 1\]"):
        load_subject(subject_dir)


@pytest.mark.parametrize("entry", [(0, 0), (1, 1)])
def test_non_positive_focal(subject_dir, entry):
    def zero(a):
        a = a.copy()
        a[4][entry] = -10.0 if entry == (1, 1) else 0.0
        return a

    rewrite_frames(subject_dir, K=zero)
    with pytest.raises(FormatError, match=r"frames\.npz: K: non-positive focal length in frame 4"):
        load_subject(subject_dir)


def test_unsafe_frame_name(subject_dir):
    rewrite_frames(subject_dir, frame_names=np.array(["000000", "../evil", "000002", "000003", "000004"]))
    with pytest.raises(FormatError, match=r"frames\.npz: frame_names: frame 1: '\.\./evil' is not a safe file stem"):
        load_subject(subject_dir)


@pytest.mark.parametrize("bad", ["000001\n", "000001\r", "0001 a", ""])
def test_frame_names_must_match_in_full(subject_dir, bad):
    # "$" in a search matches before a final newline: the whole name must match (issue 18, case 5).
    rewrite_frames(subject_dir, frame_names=np.array(["000000", bad, "000002", "000003", "000004"]))
    with pytest.raises(FormatError, match=r"frames\.npz: frame_names: frame 1: .* is not a safe file stem"):
        load_subject(subject_dir)


def test_duplicate_frame_names(subject_dir):
    rewrite_frames(subject_dir, frame_names=np.array(["000000", "000000", "000002", "000003", "000004"]))
    with pytest.raises(FormatError, match=r"frame_names: duplicate name\(s\) \['000000'\]"):
        load_subject(subject_dir)


@pytest.mark.parametrize("name", ["frames.npz", "body.npz"])
def test_npz_not_a_zip(subject_dir, name):
    (subject_dir / name).write_bytes(b"this is not an npz archive at all" * 3)
    with pytest.raises(FormatError, match=rf"{name}: not a valid \.npz archive"):
        load_subject(subject_dir)


def test_random_bytes_npz_does_not_relay_numpys_pickle_advice(subject_dir):
    # issue 18, case 8: numpy reads a file that is neither a zip nor an .npy as a pickle
    (subject_dir / "frames.npz").write_bytes(np.random.default_rng(0).bytes(400))
    with pytest.raises(FormatError, match=r"frames\.npz: not a valid \.npz archive \(not a zip of \.npy arrays") as err:
        load_subject(subject_dir)
    assert "pickle" not in str(err.value)


def test_unknown_and_oversized_arrays_are_refused_before_decompression(subject_dir, monkeypatch):
    # issue 18, case 10: a 420 KB frames.npz once made 469 MB of memory (an unknown array) and passed validation
    import zipfile

    with np.load(subject_dir / "frames.npz", allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    reads = []
    real_open = zipfile.ZipFile.open

    def opened(self, name, *args, **kw):
        reads.append((Path(self.filename).name, name))
        return real_open(self, name, *args, **kw)

    np.savez_compressed(subject_dir / "frames.npz", **arrays, junk=np.zeros((4096, 4096)))
    monkeypatch.setattr(zipfile.ZipFile, "open", opened)
    with pytest.raises(FormatError, match=r"frames\.npz: junk: unknown array, not read \(this format has \["):
        load_subject(subject_dir)
    assert [r for r in reads if r[0] == "frames.npz"] == []  # no array of it was decompressed
    monkeypatch.undo()
    np.savez_compressed(subject_dir / "frames.npz", **{**arrays, "trans": np.zeros((5, 4096, 3))})
    monkeypatch.setattr(zipfile.ZipFile, "open", opened)
    with pytest.raises(FormatError, match=r"frames\.npz: trans: 491648 bytes once decompressed, more than the \d+ "):
        load_subject(subject_dir)
    assert [r for r in reads if r[0] == "frames.npz"] == []


def test_npz_truncated(subject_dir):
    data = (subject_dir / "frames.npz").read_bytes()
    (subject_dir / "frames.npz").write_bytes(data[: len(data) // 2])
    with pytest.raises(FormatError, match=r"frames\.npz: "):
        load_subject(subject_dir)


def test_npz_is_a_single_npy(subject_dir):
    with open(subject_dir / "frames.npz", "wb") as f:
        np.save(f, np.zeros(3))
    with pytest.raises(FormatError, match=r"frames\.npz: a single \.npy array, not an \.npz archive"):
        load_subject(subject_dir)


def test_npz_needs_pickle(subject_dir):
    rewrite_frames(subject_dir, split=np.array(["train", "train", "train", "test", {"evil": 1}], dtype=object))
    with pytest.raises(FormatError, match=r"frames\.npz: split: holds Python objects \(needs pickle\), refused"):
        load_subject(subject_dir)


def test_body_npz_invalid(subject_dir):
    with np.load(subject_dir / "body.npz", allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    arrays["skin_weights"] = arrays["skin_weights"] * 2
    np.savez(subject_dir / "body.npz", **arrays)
    with pytest.raises(FormatError, match=r"body\.npz: skin_weights: rows must sum to 1"):
        load_subject(subject_dir)


def test_body_npz_missing_array(subject_dir):
    with np.load(subject_dir / "body.npz", allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files if k != "faces"}
    np.savez(subject_dir / "body.npz", **arrays)
    with pytest.raises(FormatError, match=r"body\.npz: faces: missing array"):
        load_subject(subject_dir)


@pytest.mark.parametrize("folder, kind", [("images", "image"), ("masks", "mask")])
def test_missing_frame_file(subject_dir, folder, kind):
    (subject_dir / folder / "000003.png").unlink()
    with pytest.raises(FormatError, match=rf"{folder}/000003\.png: missing {kind} for frame '000003' \(index 3\)"):
        load_subject(subject_dir)


def test_missing_images_folder(subject_dir):
    shutil.rmtree(subject_dir / "masks")
    with pytest.raises(FormatError, match=r"masks: missing folder \(5 frame masks expected\)"):
        load_subject(subject_dir)


@pytest.mark.parametrize("folder, shape", [("images", (H, W + 1, 3)), ("masks", (H - 2, W))])
def test_wrong_image_size(subject_dir, folder, shape):
    write_png(subject_dir / folder / "000001.png", np.zeros(shape, np.float32))
    with pytest.raises(FormatError, match=rf"{folder}/000001\.png: (image|mask) size {shape[1]}x{shape[0]} \(W x H\) does not match subject\.json width x height 16x12"):
        load_subject(subject_dir)
    s = load_subject(subject_dir, check_images=False)
    with pytest.raises(FormatError, match=r"000001\.png: image size .* does not match"):
        (s.image if folder == "images" else s.mask)(1)


def test_wrong_image_kind(subject_dir):
    write_png(subject_dir / "masks" / "000000.png", np.zeros((H, W, 3), np.float32))
    with pytest.raises(FormatError, match=r"masks/000000\.png: expected a single-channel gray PNG, got 3 channel\(s\)"):
        load_subject(subject_dir)


def test_corrupt_image(subject_dir):
    (subject_dir / "images" / "000002.png").write_bytes(b"GIF89a not a png at all, really not")
    with pytest.raises(FormatError, match=r"images/000002\.png: not a PNG file .*\(image of frame '000002'\)"):
        load_subject(subject_dir)


def test_format_error_is_value_error():
    assert issubclass(FormatError, ValueError)


# ------------------------------------------------------------------------------------------------
# trioman inspect


def _cli(monkeypatch):
    """trioman.cli with only the commands whose modules exist (others may be written later)."""
    from trioman import cli

    present = tuple(c for c in cli.COMMANDS if importlib.util.find_spec(c.module) is not None)
    monkeypatch.setattr(cli, "COMMANDS", present)
    return cli


def test_inspect_valid(subject_dir, capsys, monkeypatch):
    cli = _cli(monkeypatch)
    assert cli.main(["inspect", str(subject_dir)]) == 0
    out = capsys.readouterr().out
    assert "frames      5 (train 3, test 2)" in out
    assert "16 x 12 (W x H)" in out
    assert "test-chain: 3 joints, 6 vertices, 4 faces" in out
    lines = out.splitlines()
    assert any(line.split() == ["walk", "3", "0"] for line in lines)
    assert any(line.split() == ["dance", "0", "2"] for line in lines)
    assert "camera      distance to root joint" in out
    assert "pose_noise_sigma = 0.05" in out
    assert "poses_true  recorded" in out
    assert out.rstrip().endswith("valid")


def test_inspect_broken(subject_dir, capsys, monkeypatch):
    cli = _cli(monkeypatch)
    (subject_dir / "masks" / "000004.png").unlink()
    assert cli.main(["inspect", str(subject_dir)]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert err.startswith("trioman inspect: error: ")
    assert "000004.png: missing mask for frame '000004'" in err
    # --no-images skips the per-frame file check
    assert cli.main(["inspect", "--no-images", str(subject_dir)]) == 0


def test_inspect_not_a_subject(tmp_path, capsys, monkeypatch):
    cli = _cli(monkeypatch)
    assert cli.main(["inspect", str(tmp_path)]) == 1
    assert "subject.json: missing file" in capsys.readouterr().err


# ------------------------------------------------------------------------------------------------
# no torch in the runtime


def test_load_without_torch(subject_dir, tmp_path):
    blocker = tmp_path / "block"
    blocker.mkdir()
    (blocker / "torch.py").write_text("raise ImportError('torch is blocked in this test')\n")
    code = textwrap.dedent(
        f"""
        import sys
        sys.modules["torch"] = None  # import torch -> ImportError
        from trioman.runtime.formats import load_subject
        import trioman.runtime.image_io, trioman.runtime.inspect, trioman.runtime.skeleton
        s = load_subject({str(subject_dir)!r})
        assert s.image(0).shape == (12, 16, 3)
        from trioman import cli
        assert cli.main(["inspect", {str(subject_dir)!r}]) == 0  # the CLI itself, torch blocked
        loaded = sorted(m for m in sys.modules if m == "torch" or m.startswith("torch."))
        assert sys.modules["torch"] is None and loaded == ["torch"], loaded
        print("ok", s.num_frames)
        """
    )
    env = dict(os.environ, PYTHONPATH=str(blocker) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert "ok 5" in proc.stdout


def test_runtime_modules_do_not_import_torch():
    """Every trioman.runtime module imports without torch (an import of torch would raise)."""
    runtime = Path(__file__).resolve().parents[2] / "runtime"
    modules = sorted(p.stem for p in runtime.glob("*.py") if p.stem != "__init__")
    code = textwrap.dedent(
        f"""
        import sys, importlib
        sys.modules["torch"] = None
        for name in {modules!r}:
            importlib.import_module("trioman.runtime." + name)
        bad = [m for m in sys.modules if m.startswith("torch.") or (m == "torch" and sys.modules[m] is not None)]
        assert not bad, bad
        print("imported", len({modules!r}))
        """
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert f"imported {len(modules)}" in proc.stdout
