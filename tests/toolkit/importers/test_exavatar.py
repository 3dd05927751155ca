"""trioman import exavatar / smplx-fits on tiny captures in each layout, with the fake SMPL-X model."""

from __future__ import annotations

import functools

import numpy as np
import pytest

torch = pytest.importorskip("torch")
smplx = pytest.importorskip("smplx", reason="needs the 'smplx' extra: pip install 'trioman[smplx]'")

from trioman.cli import main  # noqa: E402
from trioman.runtime.formats import load_subject  # noqa: E402
from tests.toolkit.importers import layouts  # noqa: E402

WRITERS = {"xhumans": layouts.write_xhumans, "neuman": layouts.write_neuman, "custom": layouts.write_custom}
SUBJECT_ID = {"xhumans": "00028", "neuman": "bike", "custom": "myvideo"}


@functools.lru_cache(maxsize=2)
def smplx_layer(model_dir, gender: str, num_betas: int):
    return smplx.SMPLX(str(model_dir), gender=gender, num_betas=num_betas, use_pca=False, flat_hand_mean=False,
                       dtype=torch.float64)


@torch.no_grad()
def reference_pixels(model_dir, scene, frame, gender="male", num_betas=layouts.NUM_BETAS) -> np.ndarray:
    """smplx's own joints for the written parameters, projected with the written camera. -> [55, 2]."""
    layer = smplx_layer(model_dir, gender, num_betas)
    p = {k: torch.tensor(np.asarray(v, dtype=np.float64)).reshape(1, -1) for k, v in frame["params"].items() if k != "expr"}
    out = layer(betas=torch.tensor(scene.betas)[None], global_orient=p["root_pose"], body_pose=p["body_pose"],
                jaw_pose=p["jaw_pose"], leye_pose=p["leye_pose"], reye_pose=p["reye_pose"],
                left_hand_pose=p["lhand_pose"], right_hand_pose=p["rhand_pose"], transl=p["trans"])
    X = out.joints[0, :55].numpy()
    cam = X if frame["in_camera"] else X @ frame["R"].T + frame["t"]
    return np.asarray(layouts.FOCAL) * cam[:, :2] / cam[:, 2:] + np.asarray(layouts.PRINCPT)


def subject_pixels(subject, i: int) -> np.ndarray:
    G = subject.body.skeleton.forward_kinematics(subject.poses[i], subject.trans[i])
    X = G[:, :3, 3] @ subject.viewmat[i, :3, :3].T.astype(np.float64) + subject.viewmat[i, :3, 3]
    uv = X @ subject.K[i].T.astype(np.float64)
    return uv[:, :2] / uv[:, 2:]


def run_import(tmp_path, dataset, model_dir, *extra):
    root = tmp_path / "data"
    scene = WRITERS[dataset](root, model_dir)
    out = tmp_path / f"subject_{dataset}"
    args = ["import", "exavatar", str(root), "--dataset", dataset, "--subject", SUBJECT_ID[dataset], "--out", str(out),
            "--body-model-dir", str(model_dir), *extra]
    return scene, out, main(args)


@pytest.mark.parametrize("dataset", ["xhumans", "neuman", "custom"])
def test_imported_joints_project_to_the_known_pixels(tmp_path, smplx_model_dir, dataset, capsys):
    extra = ("--allow-pickle",) if dataset == "xhumans" else ()
    scene, out, rc = run_import(tmp_path, dataset, smplx_model_dir, *extra)
    assert rc == 0, capsys.readouterr().err
    assert "expression coefficients are ignored" in capsys.readouterr().out
    subject = load_subject(out)
    assert subject.body_model == "smplx" and subject.num_joints == 55 and subject.body.pose_correctives is not None
    assert [f["name"] for f in scene.frames] == subject.frame_names.tolist()
    assert [f["split"] for f in scene.frames] == subject.split.tolist()
    for i, frame in enumerate(scene.frames):
        got = subject_pixels(subject, i)
        np.testing.assert_allclose(got[0], layouts.PRINCPT, atol=1e-3)  # the pelvis: on the optical axis
        np.testing.assert_allclose(got, reference_pixels(smplx_model_dir, scene, frame), atol=1e-2)
    # Images are premultiplied by the mask: black outside the disc, the person inside.
    img, mask = subject.image(0), subject.mask(0)
    assert mask[33, 31] == 1.0 and mask[0, 0] == 0.0 and np.all(img[0, 0] == 0) and img[33, 31].max() > 0


def test_neuman_test_frames_use_the_segmentation_masks(tmp_path, smplx_model_dir):
    """Training frames: masks/ (binarised at 0.5); test frames: 1 - segmentations/ / 255 (ExAvatar's evaluation)."""
    root = tmp_path / "data"
    layouts.write_neuman(root, smplx_model_dir)
    seg = np.full((layouts.SIZE, layouts.SIZE), 255, np.uint8)
    seg[10:20, 10:20] = 0  # the person, for the evaluation
    layouts._png(root / "bike" / "segmentations" / "00004.png", seg)
    out = tmp_path / "subject"
    assert main(["import", "exavatar", str(root / "bike"), "--dataset", "neuman", "--out", str(out),
                 "--body-model-dir", str(smplx_model_dir)]) == 0
    subject = load_subject(out)
    i = subject.frame_names.tolist().index("00004")
    np.testing.assert_array_equal(subject.mask(i), 1.0 - seg / 255.0)
    assert subject.mask(0)[33, 31] == 1.0 and subject.mask(0)[12, 12] == 0.0


def test_smplx_fits_round_trip(tmp_path, smplx_model_dir, capsys):
    scene = layouts.write_smplerx(tmp_path, smplx_model_dir)
    out = tmp_path / "subject"
    rc = main(["import", "smplx-fits", str(tmp_path / "frames"), str(tmp_path / "fits"), "--out", str(out),
               "--body-model-dir", str(smplx_model_dir)])
    assert rc == 0, capsys.readouterr().err
    subject = load_subject(out)
    assert subject.split.tolist() == [f["split"] for f in scene.frames]
    for i, frame in enumerate(scene.frames):
        want = reference_pixels(smplx_model_dir, scene, frame, gender="neutral", num_betas=10)
        np.testing.assert_allclose(subject_pixels(subject, i), want, atol=1e-2)
