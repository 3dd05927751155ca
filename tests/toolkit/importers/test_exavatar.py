"""trioman import exavatar / smplx-fits on tiny captures in each layout, with the fake SMPL-X model."""

from __future__ import annotations

import contextlib
import pickle

import numpy as np
import pytest

torch = pytest.importorskip("torch")
smplx = pytest.importorskip("smplx", reason="needs the 'smplx' extra: pip install 'trioman[smplx]'")

from trioman.cli import main  # noqa: E402
from trioman.runtime.formats import load_subject  # noqa: E402
from trioman.toolkit.body.smplx_model import JOINT_NAMES, Y_UP_TO_Z_UP  # noqa: E402
from tests.toolkit.importers import layouts  # noqa: E402

WRITERS = {"xhumans": layouts.write_xhumans, "neuman": layouts.write_neuman, "custom": layouts.write_custom}
SUBJECT_ID = {"xhumans": "00028", "neuman": "bike", "custom": "myvideo"}


_LAYERS: dict = {}


def smplx_layer(model_dir, gender: str, num_betas: int, face_offset):
    """smplx's SMPL-X layer; ExAvatar's face_offset is added to the template (its smplx fork, body_models.py
    line 1250: v_template + face_offset)."""
    key = (str(model_dir), gender, num_betas, None if face_offset is None else hash(face_offset.tobytes()))
    if key not in _LAYERS:
        with np.load(model_dir / f"SMPLX_{gender.upper()}.npz", allow_pickle=False) as f:
            template = f["v_template"] + (0 if face_offset is None else face_offset)
        _LAYERS.clear()
        _LAYERS[key] = smplx.SMPLX(str(model_dir), gender=gender, num_betas=num_betas, use_pca=False,
                                   flat_hand_mean=False, v_template=template, dtype=torch.float64)
    return _LAYERS[key]


@contextlib.contextmanager
def joint_offset_added(joint_offset):
    """smplx's forward with ExAvatar's joint offset: added to the regressed joints (ExAvatar_RELEASE's smplx fork,
    fitting/common/utils/smplx/smplx/lbs.py lines 219-221)."""
    original = smplx.lbs.vertices2joints

    def with_offset(J_regressor, vertices):
        J = original(J_regressor, vertices)
        return J if joint_offset is None else J + torch.as_tensor(joint_offset, dtype=J.dtype)

    smplx.lbs.vertices2joints = with_offset
    try:
        yield
    finally:
        smplx.lbs.vertices2joints = original


@torch.no_grad()
def reference_vertices(model_dir, scene, frame, num_betas=None) -> np.ndarray:
    """smplx's vertices [10475, 3] for the written parameters and identity, in the written camera's frame."""
    layer = smplx_layer(model_dir, scene.gender, len(scene.betas) if num_betas is None else num_betas, scene.face_offset)
    p = {k: torch.tensor(np.asarray(v, dtype=np.float64)).reshape(1, -1) for k, v in frame["params"].items() if k != "expr"}
    with joint_offset_added(scene.joint_offset):
        out = layer(betas=torch.tensor(scene.betas)[None], global_orient=p["root_pose"], body_pose=p["body_pose"],
                    jaw_pose=p["jaw_pose"], leye_pose=p["leye_pose"], reye_pose=p["reye_pose"],
                    left_hand_pose=p["lhand_pose"], right_hand_pose=p["rhand_pose"], transl=p["trans"])
    X = out.vertices[0].numpy()
    return X if frame["in_camera"] else X @ frame["R"].T + frame["t"]


def subject_vertices(subject, i: int) -> np.ndarray:
    """The imported frame's posed vertices through its imported camera -> [10475, 3] in the camera frame."""
    X = subject.body.pose(subject.poses[i].astype(np.float64), subject.trans[i].astype(np.float64))
    return X @ subject.viewmat[i, :3, :3].T.astype(np.float64) + subject.viewmat[i, :3, 3]


def pixels(X: np.ndarray, focal, princpt) -> np.ndarray:
    return np.asarray(focal) * X[:, :2] / X[:, 2:] + np.asarray(princpt)


def check_against_smplx(subject, scene, model_dir, num_betas=None) -> None:
    """Every vertex of every frame within 1e-4 m of smplx's in the camera frame; K as written; pelvis on axis."""
    num_betas = len(scene.betas) if num_betas is None else num_betas
    assert [f["name"] for f in scene.frames] == subject.frame_names.tolist()
    assert [f["split"] for f in scene.frames] == subject.split.tolist()
    for i, frame in enumerate(scene.frames):
        got, want = subject_vertices(subject, i), reference_vertices(model_dir, scene, frame, num_betas)
        np.testing.assert_allclose(got, want, atol=1e-4, rtol=0)
        K = subject.K[i]
        np.testing.assert_allclose([K[0, 0], K[1, 1]], frame["focal"], rtol=1e-6)
        np.testing.assert_allclose([K[0, 2], K[1, 2]], frame["princpt"], rtol=1e-6)
        G = subject.body.skeleton.forward_kinematics(subject.poses[i], subject.trans[i])
        pelvis = G[:1, :3, 3] @ subject.viewmat[i, :3, :3].T.astype(np.float64) + subject.viewmat[i, :3, 3]
        np.testing.assert_allclose(pixels(pelvis, frame["focal"], frame["princpt"])[0], frame["princpt"], atol=1e-3)
    check_upright(subject, scene)


HEAD, FEET = JOINT_NAMES.index("head"), [JOINT_NAMES.index("left_foot"), JOINT_NAMES.index("right_foot")]


def check_upright(subject, scene, max_tilt_deg=10.0) -> None:
    """In every frame the head is above both feet along +z, and subject.json's capture_to_world takes the
    capture's true up (the fixture's) to within max_tilt_deg of +z."""
    for i in range(subject.num_frames):
        z = subject.body.skeleton.forward_kinematics(subject.poses[i], subject.trans[i])[:, 2, 3]
        assert z[HEAD] > z[FEET].max(), f"frame {subject.frame_names[i]}: head {z[HEAD]:.2f} m, feet {z[FEET]} m"
    up = np.asarray(subject.meta["capture_to_world"]) @ scene.up
    assert np.degrees(np.arccos(np.clip(up[2], -1, 1))) < max_tilt_deg
    assert subject.meta["generator"]["up"]["source"] == "body"


def run_import(tmp_path, dataset, model_dir, *extra):
    root = tmp_path / "data"
    scene = WRITERS[dataset](root, model_dir)
    out = tmp_path / f"subject_{dataset}"
    args = ["import", "exavatar", str(root), "--dataset", dataset, "--subject", SUBJECT_ID[dataset], "--out", str(out),
            "--body-model-dir", str(model_dir), *extra]
    return scene, out, main(args)


@pytest.mark.parametrize("dataset", ["xhumans", "neuman", "custom"])
def test_imported_vertices_match_smplx_in_the_camera(tmp_path, smplx_model_dir, dataset, capsys):
    extra = ("--allow-pickle",) if dataset == "xhumans" else ()
    scene, out, rc = run_import(tmp_path, dataset, smplx_model_dir, *extra)
    assert rc == 0, capsys.readouterr().err
    said = capsys.readouterr().out
    assert "expression coefficients are ignored" in said
    subject = load_subject(out)
    assert subject.body_model == "smplx" and subject.num_joints == 55 and subject.body.pose_correctives is not None
    check_against_smplx(subject, scene, smplx_model_dir)
    fits = subject.meta["generator"]["fits"]
    if dataset == "xhumans":  # no take holds ExAvatar's fits: X-Humans' own, on its own body (not ExAvatar's identity)
        assert fits["source"] == "xhumans" and subject.meta["generator"]["num_betas"] == 10
        assert "posed by X-Humans' own fits" in said and "00028/smplx_optimized (ExAvatar's identity) is not used" in said
    else:
        assert fits["source"] == "exavatar" and subject.meta["generator"]["num_betas"] == layouts.NUM_BETAS
    # Images are premultiplied by the mask: black outside the disc, the person inside.
    img, mask = subject.image(0), subject.mask(0)
    assert mask[33, 31] == 1.0 and mask[0, 0] == 0.0 and np.all(img[0, 0] == 0) and img[33, 31].max() > 0


def test_the_upright_check_fails_a_y_down_capture_kept_as_it_is(tmp_path, smplx_model_dir):
    """The negative control of ``check_upright``: the custom layout's world is the camera's (y down); imported with
    ``--up none`` it stays so, the person stands along -y, and the check that passes for ``--up body`` fails."""
    scene, out, rc = run_import(tmp_path, "custom", smplx_model_dir, "--up", "none")
    assert rc == 0
    with pytest.raises(AssertionError, match=r"^frame \S+: head "):  # its head is not above its feet along +z
        check_upright(load_subject(out), scene)


def test_custom_with_colmap_cameras(tmp_path, smplx_model_dir):
    """Custom with COLMAP: sparse/ names the images image{N}.jpg (ExAvatar's run_colmap.py), no cam_params/."""
    scene = layouts.write_custom(tmp_path / "data", smplx_model_dir, colmap=True)
    assert not (tmp_path / "data" / "myvideo" / "cam_params").exists()
    out = tmp_path / "subject"
    assert main(["import", "exavatar", str(tmp_path / "data" / "myvideo"), "--dataset", "custom", "--out", str(out),
                 "--body-model-dir", str(smplx_model_dir)]) == 0
    check_against_smplx(load_subject(out), scene, smplx_model_dir)


def test_neuman_as_upstream_writes_it(tmp_path, smplx_model_dir):
    """Unpadded fits and masks (N.json, N.png) beside padded images (%05d.png), ml-neuman's split files with a
    val split that is left out; padding never matters, two files of one frame are refused."""
    root = tmp_path / "data"
    layouts.write_neuman(root, smplx_model_dir)
    seq = root / "bike"
    assert (seq / "smplx_optimized" / "smplx_params" / "2.json").is_file() and (seq / "images" / "00002.png").is_file()
    assert (seq / "test_split.txt").read_text() == "00002.png\n" and (seq / "val_split.txt").read_text() == "00007.png\n"
    out = tmp_path / "subject"
    assert main(["import", "exavatar", str(seq), "--dataset", "neuman", "--out", str(out),
                 "--body-model-dir", str(smplx_model_dir)]) == 0
    subject = load_subject(out)
    assert "00007" not in subject.frame_names.tolist() and subject.frame_names[subject.indices("test")].tolist() == ["00002"]
    # padded fits (another writer's naming) are read the same
    params = seq / "smplx_optimized" / "smplx_params"
    for p in list(params.iterdir()):
        p.rename(params / f"{int(p.stem):05d}.json")
    out2 = tmp_path / "subject2"
    assert main(["import", "exavatar", str(seq), "--dataset", "neuman", "--out", str(out2),
                 "--body-model-dir", str(smplx_model_dir)]) == 0
    np.testing.assert_array_equal(load_subject(out2).poses, subject.poses)


def test_the_upright_turn_leaves_every_pixel_in_place(tmp_path, smplx_model_dir, capsys):
    """NeuMan (COLMAP world with a random up): --up none keeps the capture's world (its +y taken as up), --up
    cameras and --up body turn it; the posed body seen through each frame's camera is the same in all three."""
    root = tmp_path / "data"
    scene = layouts.write_neuman(root, smplx_model_dir)
    subjects = {}
    for up in ("none", "cameras", "body"):
        out = tmp_path / f"subject_{up}"
        assert main(["import", "exavatar", str(root / "bike"), "--dataset", "neuman", "--out", str(out),
                     "--body-model-dir", str(smplx_model_dir), "--up", up]) == 0
        assert f"world up from {'the capture' if up == 'none' else 'the ' + up}" in capsys.readouterr().out
        subjects[up] = load_subject(out)
    np.testing.assert_allclose(subjects["none"].meta["capture_to_world"], Y_UP_TO_Z_UP, atol=1e-12)
    for up in ("cameras", "body"):
        s = subjects[up]
        assert s.meta["generator"]["up"]["source"] == up
        np.testing.assert_allclose(s.K, subjects["none"].K)
        for i in range(s.num_frames):
            np.testing.assert_allclose(subject_vertices(s, i), subject_vertices(subjects["none"], i), atol=2e-5)
        tilt = np.degrees(np.arccos((np.asarray(s.meta["capture_to_world"]) @ scene.up)[2]))
        assert tilt < 10.0, f"--up {up}: the capture's up lands {tilt:.1f} deg from +z"


def test_neuman_test_frames_use_the_segmentation_masks(tmp_path, smplx_model_dir):
    """Training frames: masks/ (binarised at 0.5); test frames: 1 - segmentations/ / 255 (ExAvatar's evaluation)."""
    root = tmp_path / "data"
    layouts.write_neuman(root, smplx_model_dir)
    seg = np.full((layouts.SIZE, layouts.SIZE), 255, np.uint8)
    seg[10:20, 10:20] = 0  # the person, for the evaluation
    layouts._png(root / "bike" / "segmentations" / "00002.png", seg)
    out = tmp_path / "subject"
    assert main(["import", "exavatar", str(root / "bike"), "--dataset", "neuman", "--out", str(out),
                 "--body-model-dir", str(smplx_model_dir)]) == 0
    subject = load_subject(out)
    i = subject.frame_names.tolist().index("00002")
    np.testing.assert_array_equal(subject.mask(i), 1.0 - seg / 255.0)
    assert subject.mask(0)[33, 31] == 1.0 and subject.mask(0)[12, 12] == 0.0


def test_smplx_fits_round_trip(tmp_path, smplx_model_dir, capsys):
    scene = layouts.write_smplerx(tmp_path, smplx_model_dir)
    out = tmp_path / "subject"
    rc = main(["import", "smplx-fits", str(tmp_path / "frames"), str(tmp_path / "fits"), "--out", str(out),
               "--body-model-dir", str(smplx_model_dir)])
    assert rc == 0, capsys.readouterr().err
    assert "2 of 5 frames hold several people; person 0 of each frame is imported" in capsys.readouterr().out
    check_against_smplx(load_subject(out), scene, smplx_model_dir, num_betas=10)


def test_smplx_fits_keep_each_frames_pelvis_under_the_mean_shape(tmp_path, smplx_model_dir):
    """Per-frame betas differ; the subject has their mean, and each frame's pelvis stays where its own betas put it."""
    scene = layouts.write_smplerx(tmp_path, smplx_model_dir)
    fit = tmp_path / "fits" / "smplx" / "00001_0.npz"
    arrays = dict(np.load(fit))
    arrays["betas"] = arrays["betas"] + np.random.default_rng(0).normal(scale=1.0, size=(1, 10))
    np.savez(fit, **arrays)
    out = tmp_path / "subject"
    assert main(["import", "smplx-fits", str(tmp_path / "frames"), str(tmp_path / "fits"), "--out", str(out),
                 "--body-model-dir", str(smplx_model_dir)]) == 0
    subject = load_subject(out)
    layer = smplx_layer(smplx_model_dir, "neutral", 10, None)
    for i, frame in enumerate(scene.frames[:2]):
        p = {k: torch.tensor(np.asarray(v, dtype=np.float64)).reshape(1, -1) for k, v in frame["params"].items()}
        with torch.no_grad():
            want = layer(betas=torch.tensor(np.load(tmp_path / "fits" / "smplx" / f"0000{i + 1}_0.npz")["betas"]),
                         global_orient=p["root_pose"], body_pose=p["body_pose"], transl=p["trans"]).joints[0, 0].numpy()
        G = subject.body.skeleton.forward_kinematics(subject.poses[i], subject.trans[i])
        got = G[0, :3, 3] @ subject.viewmat[i, :3, :3].T.astype(np.float64) + subject.viewmat[i, :3, 3]
        np.testing.assert_allclose(got, want, atol=1e-5)


# --------------------------------------------------------------------------------------------------
# X-Humans: the fits that belong to the body they pose


ALL_TAKES = ("Take1", "Take2", "Take9")


def import_xhumans(tmp_path, model_dir, *extra, name="subject"):
    out = tmp_path / name
    rc = main(["import", "exavatar", str(tmp_path / "data"), "--dataset", "xhumans", "--subject", "00028", "--out",
               str(out), "--body-model-dir", str(model_dir), *extra])
    return rc, out


def test_xhumans_with_exavatars_fits_in_every_take(tmp_path, smplx_model_dir, capsys):
    """Every take holds ExAvatar's fitting output: its fits (camera frame) pose its identity (male, 100 betas,
    offsets); X-Humans' pickles are not read (no --allow-pickle needed)."""
    scene = layouts.write_xhumans(tmp_path / "data", smplx_model_dir, exavatar_takes=ALL_TAKES)
    assert scene is scene.by_source["exavatar"] and scene.face_offset is not None
    rc, out = import_xhumans(tmp_path, smplx_model_dir)
    said, err = capsys.readouterr()
    assert rc == 0, err
    assert "posed by ExAvatar's fits of 3 take(s) (Take1, Take2, Take9" in said
    subject = load_subject(out)
    check_against_smplx(subject, scene, smplx_model_dir)
    g = subject.meta["generator"]
    assert g["fits"]["source"] == "exavatar" and g["fits"]["left_out"] == [] and g["fits"]["identity"].endswith("Take1/smplx_optimized")
    assert g["gender"] == "male" and g["num_betas"] == layouts.NUM_BETAS
    # --fits xhumans: X-Humans' own fits and body, even so
    rc, out2 = import_xhumans(tmp_path, smplx_model_dir, "--fits", "xhumans", "--allow-pickle", name="subject2")
    assert rc == 0 and "--fits xhumans" in capsys.readouterr().out
    check_against_smplx(load_subject(out2), scene.by_source["xhumans"], smplx_model_dir)


def test_xhumans_with_exavatars_fits_in_some_takes(tmp_path, smplx_model_dir, capsys):
    """Only Take1 and Take2 were fitted by ExAvatar: by default X-Humans' own fits pose every take (one body per
    subject), said once; --fits exavatar imports the fitted takes and leaves Take9 out."""
    scene = layouts.write_xhumans(tmp_path / "data", smplx_model_dir, exavatar_takes=("Take1", "Take2"))
    assert scene is scene.by_source["xhumans"]
    rc, out = import_xhumans(tmp_path, smplx_model_dir, "--allow-pickle")
    said = capsys.readouterr().out
    assert rc == 0
    assert "only 2 of 3 takes hold ExAvatar's fitting output (Take9 has none; --fits exavatar imports only those)" in said
    check_against_smplx(load_subject(out), scene, smplx_model_dir)
    rc, out2 = import_xhumans(tmp_path, smplx_model_dir, "--fits", "exavatar", name="subject2")
    said = capsys.readouterr().out
    assert rc == 0 and "left out, holding none: Take9" in said
    subject = load_subject(out2)
    assert subject.meta["generator"]["fits"]["left_out"] == ["Take9"] and not len(subject.indices("test"))
    check_against_smplx(subject, scene.by_source["exavatar"], smplx_model_dir)


def test_xhumans_own_body_is_its_gender_and_mean_shape(tmp_path, smplx_model_dir, capsys):
    """X-Humans' own fits pose X-Humans' body: gender.txt's gender (here female: SMPLX_FEMALE.npz is read, a
    --gender that differs is refused) and mean_shape_smplx.npy; a frame fitted with other betas keeps its pelvis
    where its own betas put it."""
    models = tmp_path / "models"
    models.mkdir()
    for gender in ("MALE", "FEMALE"):
        (models / f"SMPLX_{gender}.npz").symlink_to(smplx_model_dir / "SMPLX_MALE.npz")
    scene = layouts.write_xhumans(tmp_path / "data", models, gender="female")
    rc, out = import_xhumans(tmp_path, smplx_model_dir, "--allow-pickle", name="no_female_model")
    assert rc == 1 and "SMPLX_FEMALE.npz" in capsys.readouterr().err and not out.exists()
    rc, out = import_xhumans(tmp_path, models, "--allow-pickle", "--gender", "male", name="male")
    err = capsys.readouterr().err.strip()
    assert rc == 1 and "\n" not in err and "--gender male" in err and "gender.txt" in err and not out.exists()
    # one frame fitted with its own betas
    fit = tmp_path / "data" / "00028" / "train" / "Take2" / "SMPLX" / "mesh-f00001_smplx.pkl"
    with open(fit, "rb") as f:
        data = pickle.load(f)
    own_betas = data["betas"] + np.random.default_rng(5).normal(scale=1.0, size=10)
    with open(fit, "wb") as f:
        pickle.dump({**data, "betas": own_betas}, f)
    rc, out = import_xhumans(tmp_path, models, "--allow-pickle")
    assert rc == 0, capsys.readouterr().err
    subject = load_subject(out)
    assert subject.meta["generator"]["gender"] == "female" and subject.meta["generator"]["fits"]["source"] == "xhumans"
    i = subject.frame_names.tolist().index("Take2_000001")
    frames = [f for n, f in enumerate(scene.frames) if n != i]
    check_against_smplx(subject_without(subject, i), layouts.Scene(betas=scene.betas, gender="female", frames=frames),
                        models)
    p = {k: torch.tensor(np.asarray(v, dtype=np.float64)).reshape(1, -1) for k, v in scene.frames[i]["params"].items()}
    with torch.no_grad():
        want = smplx_layer(models, "female", 10, None)(
            betas=torch.tensor(own_betas)[None], global_orient=p["root_pose"], body_pose=p["body_pose"],
            transl=p["trans"]).joints[0, 0].numpy()
    G = subject.body.skeleton.forward_kinematics(subject.poses[i], subject.trans[i])
    got = G[0, :3, 3] @ subject.viewmat[i, :3, :3].T.astype(np.float64) + subject.viewmat[i, :3, 3]
    np.testing.assert_allclose(got, want @ scene.frames[i]["R"].T + scene.frames[i]["t"], atol=1e-5)


class subject_without:  # noqa: N801  (a view of a subject without one frame, for check_against_smplx)
    def __init__(self, subject, drop: int):
        keep = [n for n in range(subject.num_frames) if n != drop]
        self.body, self.meta, self.num_frames = subject.body, subject.meta, len(keep)
        self.frame_names, self.split = subject.frame_names[keep], subject.split[keep]
        self.poses, self.trans, self.viewmat, self.K = (subject.poses[keep], subject.trans[keep], subject.viewmat[keep],
                                                        subject.K[keep])
