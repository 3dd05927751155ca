"""Bad captures: a one-line error naming the file and the field, and nothing written."""

from __future__ import annotations

import json

import numpy as np
import pytest

pytest.importorskip("torch")
pytest.importorskip("smplx", reason="needs the 'smplx' extra: pip install 'trioman[smplx]'")

from trioman.cli import main  # noqa: E402
from trioman.runtime.formats import FormatError  # noqa: E402
from trioman.toolkit.importers.exavatar import BodyConfig, import_exavatar  # noqa: E402
from trioman.toolkit.importers.smplx_fits import import_smplx_fits  # noqa: E402
from tests.toolkit.importers import layouts  # noqa: E402


def check_nothing_written(tmp_path, out):
    assert not out.exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(f".{out.name}")], "a temporary folder was left"


def exavatar(tmp_path, model_dir, dataset, break_it, allow_pickle=True, **body):
    root = tmp_path / "data"
    {"xhumans": layouts.write_xhumans, "neuman": layouts.write_neuman, "custom": layouts.write_custom}[dataset](root, model_dir)
    folder = root / {"xhumans": "00028", "neuman": "bike", "custom": "myvideo"}[dataset]
    break_it(folder)
    out = tmp_path / "subject"
    with pytest.raises((FormatError, ValueError, FileNotFoundError)) as err:
        import_exavatar(folder, dataset, out, BodyConfig(str(model_dir), **body), allow_pickle=allow_pickle,
                        say=lambda _: None)
    check_nothing_written(tmp_path, out)
    assert "\n" not in str(err.value)
    return str(err.value)


def edit_json(path, key, value):
    data = json.loads(path.read_text())
    data[key] = value
    path.write_text(json.dumps(data))


def test_missing_file(tmp_path, smplx_model_dir):
    msg = exavatar(tmp_path, smplx_model_dir, "neuman",
                   lambda f: (f / "smplx_optimized" / "smplx_params" / "2.json").unlink())
    assert "test_split.txt: frame 2: no SMPL-X fit (2.json) in " in msg and msg.endswith("smplx_params")


def test_wrong_shape(tmp_path, smplx_model_dir):
    path = "smplx_optimized/smplx_params_smoothed/1.json"
    msg = exavatar(tmp_path, smplx_model_dir, "custom", lambda f: edit_json(f / path, "body_pose", [[0.0] * 3] * 20))
    assert msg.endswith("1.json: body_pose: expected shape [21, 3] (63 values), got [20, 3]")


def test_nan_in_json_and_in_npz(tmp_path, smplx_model_dir):
    path = "smplx_optimized/smplx_params_smoothed/2.json"
    msg = exavatar(tmp_path, smplx_model_dir, "custom", lambda f: edit_json(f / path, "trans", [float("nan"), 0, 0]))
    assert "2.json: trans: NaN or Infinity, which JSON does not allow" in msg
    layouts.write_smplerx(tmp_path / "fits_case", smplx_model_dir)
    fit = tmp_path / "fits_case" / "fits" / "smplx" / "00003_0.npz"
    arrays = dict(np.load(fit))
    arrays["transl"] = np.array([[0.0, np.inf, 0.0]])
    np.savez(fit, **arrays)
    out = tmp_path / "subject2"
    with pytest.raises(FormatError, match=r"00003_0.npz: transl: 1 non-finite value\(s\)"):
        import_smplx_fits(tmp_path / "fits_case" / "frames", tmp_path / "fits_case" / "fits", out, smplx_model_dir)
    check_nothing_written(tmp_path, out)


def test_frame_counts_disagree(tmp_path, smplx_model_dir):
    def one_camera_too_few(folder):
        cams = folder / "train" / "Take2" / "render" / "cameras.npz"
        arrays = dict(np.load(cams))
        np.savez(cams, intrinsic=arrays["intrinsic"], extrinsic=arrays["extrinsic"][:1])

    msg = exavatar(tmp_path, smplx_model_dir, "xhumans", one_camera_too_few)
    assert "Take2/render/cameras.npz: extrinsic: 1 cameras for 2 images" in msg
    layouts.write_smplerx(tmp_path / "fits_case", smplx_model_dir)
    (tmp_path / "fits_case" / "fits" / "smplx" / "00003_0.npz").unlink()
    out = tmp_path / "subject2"
    with pytest.raises(FormatError, match=r"no SMPL-X fit for frame 3 \(000003.jpg\); 5 frames, 4 SMPL-X fits"):
        import_smplx_fits(tmp_path / "fits_case" / "frames", tmp_path / "fits_case" / "fits", out, smplx_model_dir)
    check_nothing_written(tmp_path, out)


def test_split_list_naming_a_missing_frame(tmp_path, smplx_model_dir):
    msg = exavatar(tmp_path, smplx_model_dir, "neuman",
                   lambda f: (f / "test_split.txt").write_text("00002.png\n00042.png\n"))
    assert "test_split.txt: frame 42: no image in" in msg


def test_unknown_gender(tmp_path, smplx_model_dir):
    msg = exavatar(tmp_path, smplx_model_dir, "custom", lambda f: None, gender="other")
    assert msg == "gender: unknown gender 'other'; expected one of ['neutral', 'male', 'female']"


def test_smplx_file_lacking_a_key(tmp_path, smplx_model_dir):
    models = tmp_path / "models"
    models.mkdir()
    arrays = dict(np.load(smplx_model_dir / "SMPLX_MALE.npz", allow_pickle=True))
    del arrays["weights"]
    np.savez(models / "SMPLX_MALE.npz", **arrays)
    msg = exavatar(tmp_path, models, "custom", lambda f: None)
    assert msg.endswith("SMPLX_MALE.npz: weights: missing array (not an SMPL-X model file?)")


def test_pickles_need_allow_pickle(tmp_path, smplx_model_dir):
    msg = exavatar(tmp_path, smplx_model_dir, "xhumans", lambda f: None, allow_pickle=False)
    assert "mesh-f00001_smplx.pkl: a pickled file" in msg and "`allow_pickle`" in msg


def test_missing_model_file_from_the_command_line(tmp_path, smplx_model_dir, capsys):
    layouts.write_custom(tmp_path / "data", smplx_model_dir)
    out = tmp_path / "subject"
    rc = main(["import", "exavatar", str(tmp_path / "data"), "--dataset", "custom", "--subject", "myvideo",
               "--out", str(out), "--body-model-dir", str(tmp_path / "nowhere")])
    err = capsys.readouterr().err.strip()
    assert rc == 1 and "\n" not in err
    assert "SMPLX_MALE.npz: SMPL-X model file not found" in err and "licensed" in err and "nowhere" in err
    check_nothing_written(tmp_path, out)


def test_capture_to_world_must_be_a_rotation(tmp_path, smplx_model_dir):
    """subject.json's capture_to_world (written by the importers) is checked on load: a 3 x 3 rotation."""
    from trioman.runtime.formats import load_subject

    layouts.write_custom(tmp_path / "data", smplx_model_dir)
    out = tmp_path / "subject"
    import_exavatar(tmp_path / "data" / "myvideo", "custom", out, BodyConfig(str(smplx_model_dir)), say=lambda _: None)
    meta_path = out / "subject.json"
    meta = json.loads(meta_path.read_text())
    R = np.asarray(meta["capture_to_world"])
    assert np.allclose(R @ R.T, np.eye(3)) and np.linalg.det(R) > 0
    for bad, why in ((np.diag([1.0, 1.0, -1.0]).tolist(), "not a rotation"), ([[1, 0, 0], [0, 1, 0]], "3 x 3")):
        meta_path.write_text(json.dumps({**meta, "capture_to_world": bad}))
        with pytest.raises(FormatError, match=f"capture_to_world.*{why}"):
            load_subject(out)


def test_up_body_needs_a_common_spine_direction(tmp_path, smplx_model_dir):
    """--up body on fits whose roots point every way (no person stands like that) says to pick another source."""
    def scatter_roots(folder):
        fits = folder / "smplx_optimized" / "smplx_params_smoothed"
        for n, axis in enumerate(([0, 0, 0], [np.pi, 0, 0], [np.pi / 2, 0, 0], [-np.pi / 2, 0, 0])):
            edit_json(fits / f"{n}.json", "root_pose", axis)

    msg = exavatar(tmp_path, smplx_model_dir, "custom", scatter_roots)
    assert msg.startswith("up body: the body's spine points in no common direction") and "`up` cameras" in msg


# --------------------------------------------------------------------------------------------------
# X-Humans' fit sources


def test_xhumans_takes_fitted_with_different_identities(tmp_path, smplx_model_dir):
    """ExAvatar fits each take with its own identity; one subject has one body, so two identities are refused."""
    def refit_take2(folder):
        shape = folder / "train" / "Take2" / "smplx_optimized" / "shape_param.json"
        shape.write_text(json.dumps((np.array(json.loads(shape.read_text())) + 0.1).tolist()))

    root = tmp_path / "data"
    layouts.write_xhumans(root, smplx_model_dir, exavatar_takes=("Take1", "Take2", "Take9"))
    refit_take2(root / "00028")
    out = tmp_path / "subject"
    with pytest.raises(FormatError) as err:
        import_exavatar(root / "00028", "xhumans", out, BodyConfig(str(smplx_model_dir)), say=lambda _: None)
    msg = str(err.value)
    assert "Take2/smplx_optimized: another identity than" in msg and "Take1/smplx_optimized" in msg and "\n" not in msg
    check_nothing_written(tmp_path, out)


def test_xhumans_exavatar_fit_missing_for_an_image(tmp_path, smplx_model_dir):
    def drop(folder):
        (folder / "train" / "Take1" / "smplx_optimized" / "smplx_params" / "2.json").unlink()

    root = tmp_path / "data"
    layouts.write_xhumans(root, smplx_model_dir, exavatar_takes=("Take1", "Take2", "Take9"))
    drop(root / "00028")
    out = tmp_path / "subject"
    with pytest.raises(FormatError, match=r"Take1/smplx_optimized/smplx_params: no fit for frame 2 \(color_000002.png\)"):
        import_exavatar(root / "00028", "xhumans", out, BodyConfig(str(smplx_model_dir)), fits="exavatar",
                        say=lambda _: None)
    check_nothing_written(tmp_path, out)


def test_xhumans_own_body_files(tmp_path, smplx_model_dir):
    msg = exavatar(tmp_path, smplx_model_dir, "xhumans", lambda f: (f / "gender.txt").unlink())
    assert msg.endswith("gender.txt: missing file (X-Humans' subject gender, which its fits were made for)")
    msg = exavatar(tmp_path / "b", smplx_model_dir, "xhumans", lambda f: (f / "gender.txt").write_text("robot\n"))
    assert "gender.txt: expected one of ['neutral', 'male', 'female'] on the first line, got 'robot'" in msg
    msg = exavatar(tmp_path / "c", smplx_model_dir, "xhumans", lambda f: np.save(f / "mean_shape_smplx.npy", [np.nan] * 10))
    assert msg.endswith("mean_shape_smplx.npy: betas: 10 non-finite value(s) (NaN/Inf)")
    msg = exavatar(tmp_path / "d", smplx_model_dir, "xhumans", lambda f: None, num_betas=100)
    assert msg.startswith("num_betas 100: X-Humans' own fits were made for its own body, whose value is 10")


def test_fits_flag_only_for_xhumans(tmp_path, smplx_model_dir):
    layouts.write_custom(tmp_path / "data", smplx_model_dir)
    with pytest.raises(ValueError, match="fits xhumans: .*only with `dataset` xhumans"):
        import_exavatar(tmp_path / "data" / "myvideo", "custom", tmp_path / "subject", BodyConfig(str(smplx_model_dir)),
                        fits="xhumans", say=lambda _: None)


# --------------------------------------------------------------------------------------------------
# never into or over the input; one JSON reader (issue 26, cases 1 and 6)


def tree(folder):
    return sorted((p.relative_to(folder).as_posix(), p.stat().st_size) for p in folder.rglob("*"))


@pytest.mark.parametrize("where", ["capture", "inside", "parent"])
def test_out_onto_or_into_the_capture_is_refused_before_any_work(tmp_path, smplx_model_dir, capsys, where):
    """--out CAPTURE (even with --overwrite), --out CAPTURE/sub or --out ROOT holding the capture: one line before
    anything is read (the body-model folder does not even exist), nothing deleted or created in the capture."""
    root = tmp_path / "data"
    layouts.write_custom(root, smplx_model_dir)
    capture = root / "myvideo"
    before = tree(root)
    out = {"capture": capture, "inside": capture / "subject", "parent": root}[where]
    rc = main(["import", "exavatar", str(root), "--dataset", "custom", "--subject", "myvideo", "--out", str(out),
               "--body-model-dir", str(tmp_path / "nowhere"), "--overwrite"])
    err = capsys.readouterr().err.strip()
    assert rc == 1 and "\n" not in err
    what = {"capture": "is the input", "inside": "lies inside the input", "parent": "holds the input"}[where]
    assert what in err and "nowhere" not in err
    assert tree(root) == before


def test_library_import_refuses_its_input_before_reading(tmp_path, smplx_model_dir):
    """import_exavatar and import_smplx_fits check the output first: a capture whose fits are broken still gets the
    input refusal, not a fit error."""
    root = tmp_path / "data"
    layouts.write_neuman(root, smplx_model_dir)
    (root / "bike" / "smplx_optimized" / "smplx_params" / "2.json").write_text("{broken")
    with pytest.raises(ValueError, match="lies inside the input"):
        import_exavatar(root / "bike", "neuman", root / "bike" / "out", BodyConfig(str(smplx_model_dir)),
                        say=lambda _: None)
    assert not (root / "bike" / "out").exists()
    layouts.write_smplerx(tmp_path / "fits_case", smplx_model_dir)
    frames, fits = tmp_path / "fits_case" / "frames", tmp_path / "fits_case" / "fits"
    for out in (fits / "subject", frames, tmp_path / "fits_case" / "masks" / "subject"):
        with pytest.raises(ValueError, match="the input"):
            import_smplx_fits(frames, fits, out, tmp_path / "nowhere")
    assert not (fits / "subject").exists() and not (tmp_path / "fits_case" / "masks" / "subject").exists()


def test_a_fit_nested_too_deeply_names_the_file(tmp_path, smplx_model_dir):
    """A fit JSON nested deeper than Python's parser recurses: one FormatError naming the file (the importers read
    JSON with formats.common.read_json)."""
    path = "smplx_optimized/smplx_params_smoothed/1.json"
    msg = exavatar(tmp_path, smplx_model_dir, "custom", lambda f: (f / path).write_text("[" * 200_000 + "]" * 200_000))
    assert msg.endswith("1.json: malformed JSON: nested too deeply to read")
