"""Bad input in every layout the fixtures write (tests/toolkit/importers/layouts.py), through the command line:
each case is one line naming the file (its path) and the field, exit status 1, and nothing written: no subject
folder, no temporary sibling.

Cases: a missing frame (an image, mask, fit or camera gone), an extra frame (a split line or a fit without an
image), NaN as the writers' ``json.dump`` leaves it (a bare ``NaN``) and as an overflowing number (read as
Infinity), NaN in an .npz and a pickle, shape mismatches, a pickle without --allow-pickle, a split line twice or a
frame in two splits, a NaN or negative focal in COLMAP's cameras.txt, a mask or depth map of another size."""

from __future__ import annotations

import json
import pickle
import shutil

import cv2
import numpy as np
import pytest

pytest.importorskip("torch")
pytest.importorskip("smplx", reason="needs the 'smplx' extra: pip install 'trioman[smplx]'")

from trioman.cli import main  # noqa: E402
from tests.toolkit.importers import layouts  # noqa: E402

ALL_TAKES = ("Take1", "Take2", "Take9")


def _xhumans(root, model_dir):
    layouts.write_xhumans(root, model_dir)
    return root / "00028", ["exavatar", str(root), "--dataset", "xhumans", "--subject", "00028", "--allow-pickle"]


def _xhumans_exavatar(root, model_dir):
    layouts.write_xhumans(root, model_dir, exavatar_takes=ALL_TAKES)
    return root / "00028", ["exavatar", str(root), "--dataset", "xhumans", "--subject", "00028"]


def _neuman(root, model_dir):
    layouts.write_neuman(root, model_dir)
    return root / "bike", ["exavatar", str(root / "bike"), "--dataset", "neuman"]


def _custom(root, model_dir):
    layouts.write_custom(root, model_dir)
    return root / "myvideo", ["exavatar", str(root / "myvideo"), "--dataset", "custom"]


def _custom_colmap(root, model_dir):
    layouts.write_custom(root, model_dir, colmap=True)
    return root / "myvideo", ["exavatar", str(root / "myvideo"), "--dataset", "custom"]


def _smplerx(root, model_dir):
    layouts.write_smplerx(root, model_dir)
    return root, ["smplx-fits", str(root / "frames"), str(root / "fits")]


WRITERS = {"xhumans": _xhumans, "xhumans_exavatar": _xhumans_exavatar, "neuman": _neuman, "custom": _custom,
           "custom_colmap": _custom_colmap, "smplerx": _smplerx}


# --------------------------------------------------------------------------------------------------
# ways to break a file


def json_value(path, key, text):
    """Set ``key`` of a JSON object to the raw JSON ``text`` (``NaN`` as Python's json.dump writes a float nan)."""
    data = json.loads(path.read_text())
    data[key] = "@@"
    path.write_text(json.dumps(data).replace('"@@"', text))


def npz_value(path, key, value):
    arrays = dict(np.load(path))
    arrays[key] = np.asarray(value)
    np.savez(path, **arrays)


def pickle_value(path, key, value):
    with open(path, "rb") as f:
        data = pickle.load(f)
    data[key] = np.asarray(value)
    with open(path, "wb") as f:
        pickle.dump(data, f)


def replace_line(path, old, new):
    lines = path.read_text().splitlines()
    hits = [n for n, ln in enumerate(lines) if old in ln and not ln.startswith("#")]
    assert hits, f"{path}: no line with {old!r}"
    if new is None:
        del lines[hits[0]]
    else:
        lines[hits[0]] = lines[hits[0]].replace(old, new)
    path.write_text("\n".join(lines) + "\n")


def colmap_image_line(path, name, column, value):
    """Set one column of the images.txt line naming ``name``."""
    lines = path.read_text().splitlines()
    n = next(n for n, ln in enumerate(lines) if ln.endswith(f" {name}"))
    tok = lines[n].split()
    tok[column] = value
    lines[n] = " ".join(tok)
    path.write_text("\n".join(lines) + "\n")


def small_image(path, dtype=np.uint8, value=255):
    img = np.full((32, 32), value, dtype)
    img[:4] = 0
    cv2.imwrite(str(path), img)


def appended(path, text):
    path.write_text(path.read_text() + text)


FITS_N = "smplx_optimized/smplx_params"  # NeuMan's, and ExAvatar's under an X-Humans take
FITS_C = "smplx_optimized/smplx_params_smoothed"  # Custom's
NAN3 = "[NaN, 0.0, 0.0]"  # json.dump([float('nan'), 0.0, 0.0])
INF3 = "[1e999, 0.0, 0.0]"  # parsed as Infinity

# id: (layout, break(folder), the pieces the one line must hold: the file's path and the field)
CASES = {
    # NeuMan
    "neuman-missing-image": ("neuman", lambda f: (f / "images/00003.png").unlink(),
                             ["bike/train_split.txt: frame 3: no image in", "bike/images"]),
    "neuman-missing-mask": ("neuman", lambda f: (f / "masks/4.png").unlink(),
                            ["bike/train_split.txt: frame 4: no mask in", "bike/masks"]),
    "neuman-missing-fit": ("neuman", lambda f: (f / FITS_N / "5.json").unlink(),
                           ["bike/train_split.txt: frame 5: no SMPL-X fit (5.json) in", f"bike/{FITS_N}"]),
    "neuman-missing-camera": ("neuman", lambda f: replace_line(f / "sparse/images.txt", "00006.png", None),
                              ["bike/train_split.txt: frame 6: no camera for 00006.png in", "bike/sparse/images.txt"]),
    "neuman-extra-frame": ("neuman", lambda f: appended(f / "test_split.txt", "00042.png\n"),
                           ["bike/test_split.txt: frame 42: no image in"]),
    "neuman-nan-fit": ("neuman", lambda f: json_value(f / FITS_N / "3.json", "trans", NAN3),
                       [f"bike/{FITS_N}/3.json: trans: NaN"]),
    "neuman-inf-fit": ("neuman", lambda f: json_value(f / FITS_N / "3.json", "root_pose", INF3),
                       [f"bike/{FITS_N}/3.json: root_pose: 1 non-finite value(s)"]),
    "neuman-fit-shape": ("neuman", lambda f: json_value(f / FITS_N / "4.json", "lhand_pose", json.dumps([[0.0] * 3] * 14)),
                         [f"bike/{FITS_N}/4.json: lhand_pose: expected shape [15, 3] (45 values), got [14, 3]"]),
    "neuman-identity-shape": ("neuman", lambda f: (f / "smplx_optimized/joint_offset.json").write_text(
        json.dumps([[0.0] * 3] * 54)), ["bike/smplx_optimized/joint_offset.json: joint_offset: expected shape [55, 3]"]),
    "neuman-split-line-twice": ("neuman", lambda f: appended(f / "train_split.txt", "00004.png\n"),
                                ["bike/train_split.txt: line 9: frame 4 is listed twice (first on line 4)"]),
    "neuman-frame-in-two-splits": ("neuman", lambda f: appended(f / "train_split.txt", "00002.png\n"),
                                   ["bike/test_split.txt: frame 2 is also in", "bike/train_split.txt"]),
    "neuman-nan-focal": ("neuman", lambda f: replace_line(f / "sparse/cameras.txt", f"{layouts.FOCAL[0]} ", "nan "),
                         ["bike/sparse/cameras.txt: camera parameters: fx fy cx cy: 1 non-finite value(s)"]),
    "neuman-negative-focal": ("neuman", lambda f: replace_line(f / "sparse/cameras.txt", f" {layouts.FOCAL[1]} ", " -72.0 "),
                              ["bike/sparse/cameras.txt: camera parameters: focal length must be > 0, got [70.0, -72.0]"]),
    "neuman-nan-quaternion": ("neuman", lambda f: colmap_image_line(f / "sparse/images.txt", "00001.png", 2, "nan"),
                              ["bike/sparse/images.txt: 00001.png: QW QX QY QZ: 1 non-finite value(s)"]),
    "neuman-mask-size": ("neuman", lambda f: small_image(f / "masks/4.png"),
                         ["bike/masks/4.png: mask of frame '00004': size 32x32 (W x H) differs from the first frame's "
                          "image 64x64"]),
    "neuman-segmentation-size": ("neuman", lambda f: small_image(f / "segmentations/00002.png"),
                                 ["bike/segmentations/00002.png: mask of frame '00002': size 32x32"]),
    "neuman-image-size": ("neuman", lambda f: cv2.imwrite(str(f / "images/00003.png"), np.zeros((32, 48, 3), np.uint8)),
                          ["bike/images/00003.png: size 48x32 (W x H) differs from the first frame's image 64x64"]),
    # Custom, virtual cameras
    "custom-missing-frame": ("custom", lambda f: (f / "frames/1.png").unlink(),
                             ["myvideo/frame_list_train.txt: frame 1: no frame in", "myvideo/frames"]),
    "custom-missing-camera": ("custom", lambda f: (f / "cam_params/2.json").unlink(),
                              ["myvideo/frame_list_train.txt: frame 2: no camera (2.json) in", "myvideo/cam_params"]),
    "custom-extra-frame": ("custom", lambda f: appended(f / "frame_list_test.txt", "7\n"),
                           ["myvideo/frame_list_test.txt: frame 7: no frame in"]),
    "custom-nan-fit": ("custom", lambda f: json_value(f / FITS_C / "2.json", "trans", NAN3),
                       [f"myvideo/{FITS_C}/2.json: trans: NaN"]),
    "custom-nan-focal": ("custom", lambda f: json_value(f / "cam_params/1.json", "focal", "[NaN, 2000.0]"),
                         ["myvideo/cam_params/1.json: focal: NaN"]),
    "custom-inf-focal": ("custom", lambda f: json_value(f / "cam_params/1.json", "focal", "[1e999, 2000.0]"),
                         ["myvideo/cam_params/1.json: focal: 1 non-finite value(s)"]),
    "custom-zero-focal": ("custom", lambda f: json_value(f / "cam_params/1.json", "focal", "[0.0, 2000.0]"),
                          ["myvideo/cam_params/1.json: focal: focal length must be > 0, got [0.0, 2000.0]"]),
    "custom-camera-shape": ("custom", lambda f: json_value(f / "cam_params/0.json", "R", json.dumps([[1.0, 0, 0]] * 2)),
                            ["myvideo/cam_params/0.json: R: expected shape [3, 3] (9 values), got [2, 3]"]),
    "custom-fit-shape": ("custom", lambda f: json_value(f / FITS_C / "0.json", "jaw_pose", "[0.0, 0.0]"),
                         [f"myvideo/{FITS_C}/0.json: jaw_pose: expected shape [3] (3 values), got [2]"]),
    "custom-split-line-twice": ("custom", lambda f: (f / "frame_list_train.txt").write_text("0\n1\n1\n2\n"),
                                ["myvideo/frame_list_train.txt: line 3: frame 1 is listed twice (first on line 2)"]),
    "custom-mask-size": ("custom", lambda f: small_image(f / "masks/2.png"),
                         ["myvideo/masks/2.png: mask of frame '2': size 32x32"]),
    # Custom, COLMAP
    "colmap-nan-focal": ("custom_colmap", lambda f: replace_line(f / "sparse/cameras.txt", f"{layouts.FOCAL[0]} ", "NaN "),
                         ["myvideo/sparse/cameras.txt: camera parameters: fx fy cx cy: 1 non-finite value(s)"]),
    "colmap-missing-camera": ("custom_colmap", lambda f: replace_line(f / "sparse/images.txt", "image2.jpg", None),
                              ["myvideo/frame_list_train.txt: frame 2: no camera in", "myvideo/sparse/images.txt"]),
    "colmap-nan-translation": ("custom_colmap", lambda f: colmap_image_line(f / "sparse/images.txt", "image1.jpg", 6, "inf"),
                               ["myvideo/sparse/images.txt: image1.jpg: TX TY TZ: 1 non-finite value(s)"]),
    "colmap-camera-fields": ("custom_colmap", lambda f: replace_line(f / "sparse/cameras.txt", "PINHOLE", "OPENCV"),
                             ["myvideo/sparse/cameras.txt: camera: expected 'ID PINHOLE W H fx fy cx cy'"]),
    # X-Humans, ExAvatar's per-take fits
    "xhumans-exavatar-missing-fit": ("xhumans_exavatar", lambda f: (f / "train/Take1" / FITS_N / "2.json").unlink(),
                                     [f"00028/train/Take1/{FITS_N}: no fit for frame 2 (color_000002.png)"]),
    "xhumans-exavatar-extra-fit": ("xhumans_exavatar", lambda f: shutil.copy(f / "train/Take2" / FITS_N / "1.json",
                                                                             f / "train/Take2" / FITS_N / "3.json"),
                                   [f"00028/train/Take2/{FITS_N}/3.json: a fit for frame 3, which has no image in",
                                    "00028/train/Take2/render/image"]),
    "xhumans-exavatar-missing-image": ("xhumans_exavatar",
                                       lambda f: (f / "test/Take9/render/image/color_000002.png").unlink(),
                                       ["00028/test/Take9/render/cameras.npz: extrinsic: 2 cameras for 1 images in"]),
    "xhumans-exavatar-nan-fit": ("xhumans_exavatar", lambda f: json_value(f / "train/Take2" / FITS_N / "1.json",
                                                                          "root_pose", NAN3),
                                 [f"00028/train/Take2/{FITS_N}/1.json: root_pose: NaN"]),
    "xhumans-exavatar-nan-intrinsic": ("xhumans_exavatar", lambda f: npz_value(
        f / "train/Take1/render/cameras.npz", "intrinsic", [[np.nan, 0, 31], [0, 72, 33], [0, 0, 1]]),
        ["00028/train/Take1/render/cameras.npz: intrinsic: 1 non-finite value(s)"]),
    "xhumans-exavatar-extrinsic-shape": ("xhumans_exavatar", lambda f: npz_value(
        f / "train/Take1/render/cameras.npz", "extrinsic", np.zeros((2, 3, 3))),
        ["00028/train/Take1/render/cameras.npz: extrinsic: expected shape [F, 4, 4], got [2, 3, 3]"]),
    "xhumans-exavatar-identity-shape": ("xhumans_exavatar", lambda f: (
        f / "train/Take1/smplx_optimized/shape_param.json").write_text(json.dumps([0.0] * 10)),
        ["00028/train/Take1/smplx_optimized/shape_param.json: shape_param: expected shape [100] (100 values), got [10]"]),
    "xhumans-exavatar-depth-size": ("xhumans_exavatar", lambda f: small_image(
        f / "train/Take2/render/depth/depth_000001.tiff", np.float32, 2.5),
        ["00028/train/Take2/render/depth/depth_000001.tiff: mask of frame 'Take2_000001': size 32x32"]),
    # X-Humans, its own fits (pickles)
    "xhumans-nan-pickle": ("xhumans", lambda f: pickle_value(f / "train/Take2/SMPLX/mesh-f00002_smplx.pkl", "transl",
                                                            [0.0, np.nan, 0.0]),
                           ["00028/train/Take2/SMPLX/mesh-f00002_smplx.pkl: transl: 1 non-finite value(s)"]),
    "xhumans-pickle-shape": ("xhumans", lambda f: pickle_value(f / "test/Take9/SMPLX/mesh-f00001_smplx.pkl",
                                                              "body_pose", np.zeros(60)),
                             ["00028/test/Take9/SMPLX/mesh-f00001_smplx.pkl: body_pose: expected shape [21, 3] (63 "
                              "values), got [60]"]),
    "xhumans-missing-pickle": ("xhumans", lambda f: (f / "train/Take1/SMPLX/mesh-f00002_smplx.pkl").unlink(),
                               ["00028/train/Take1/SMPLX/mesh-f00002_smplx.pkl: missing file"]),
    "xhumans-pickle-without-allow-pickle": ("xhumans", "no --allow-pickle",
                                            ["00028/train/Take1/SMPLX/mesh-f00001_smplx.pkl: a pickled file",
                                             "--allow-pickle"]),
    # SMPLer-X
    "smplerx-missing-fit": ("smplerx", lambda f: (f / "fits/smplx/00003_0.npz").unlink(),
                            ["/fits: no SMPL-X fit for frame 3 (000003.jpg); 5 frames, 4 SMPL-X fits"]),
    "smplerx-extra-fit": ("smplerx", lambda f: shutil.copy(f / "fits/smplx/00003_0.npz", f / "fits/smplx/00009_0.npz"),
                          ["fits/smplx/00009_0.npz: a fit for frame 9, which has no image in", "/frames"]),
    "smplerx-missing-mask": ("smplerx", lambda f: (f / "masks/000004.png").unlink(),
                             ["/masks: no mask for frame 4 (000004.jpg); 5 frames, 4 masks"]),
    "smplerx-nan-npz": ("smplerx", lambda f: npz_value(f / "fits/smplx/00002_0.npz", "body_pose",
                                                       np.where(np.eye(21, 3) > 0, np.nan, 0.0)),
                        ["fits/smplx/00002_0.npz: body_pose: 3 non-finite value(s)"]),
    "smplerx-nan-focal": ("smplerx", lambda f: json_value(f / "fits/meta/00004_0.json", "focal", "[NaN, 80.0]"),
                          ["fits/meta/00004_0.json: focal: NaN"]),
    "smplerx-zero-focal": ("smplerx", lambda f: json_value(f / "fits/meta/00004_0.json", "focal", "[77.0, -1.0]"),
                           ["fits/meta/00004_0.json: focal: focal length must be > 0, got [77.0, -1.0]"]),
    "smplerx-fit-shape": ("smplerx", lambda f: npz_value(f / "fits/smplx/00001_0.npz", "right_hand_pose", np.zeros((15, 2))),
                          ["fits/smplx/00001_0.npz: right_hand_pose: expected shape [15, 3] (45 values), got [15, 2]"]),
    "smplerx-betas-shape": ("smplerx", lambda f: npz_value(f / "fits/smplx/00005_0.npz", "betas", np.zeros((1, 11))),
                            ["fits/smplx/00005_0.npz: betas: 11 values, but", "00001_0.npz has 10"]),
    "smplerx-mask-size": ("smplerx", lambda f: small_image(f / "masks/000003.png"),
                          ["masks/000003.png: mask of frame '000003': size 32x32"]),
}


@pytest.mark.parametrize("case", list(CASES))
def test_bad_input_is_one_line_naming_the_file_and_nothing_is_written(tmp_path, smplx_model_dir, capsys, case):
    layout, break_it, expected = CASES[case]
    folder, source = WRITERS[layout](tmp_path / "data", smplx_model_dir)
    if break_it == "no --allow-pickle":
        source.remove("--allow-pickle")
    else:
        break_it(folder)
    out = tmp_path / "subject"
    rc = main(["import", *source, "--out", str(out), "--body-model-dir", str(smplx_model_dir)])
    err = capsys.readouterr().err.strip()
    assert rc == 1 and "\n" not in err and err.startswith("trioman import: error: "), err
    for piece in expected:
        assert piece in err, f"{piece!r} not in {err!r}"
    assert not out.exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(f".{out.name}")], "a temporary folder was left"
