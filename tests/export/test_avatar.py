"""Export of a trained avatar: ONNX graph vs torch, runtime posing vs the torch model, the CLI end to end."""

import json

import numpy as np
import pytest

torch = pytest.importorskip("torch")
onnx = pytest.importorskip("onnx")

from tests.conftest import run_python  # noqa: E402
from tests.export.factories import trained_like  # noqa: E402
from tests.runtime.factories import resign  # noqa: E402
from tests.toolkit.avatar.factories import SMALL, grid_mesh  # noqa: E402
from trioman.cli import main  # noqa: E402
from trioman.export.avatar import (  # noqa: E402
    ParityError, check_onnx_parity, export_model, parity_poses, pose_dependent_onnx, torch_pose_deltas,
)
from trioman.runtime.formats import FormatError, load_avatar  # noqa: E402
from trioman.runtime.ply import read_ply  # noqa: E402
from trioman.toolkit.avatar.model import AvatarConfig, GaussianAvatar  # noqa: E402

ATOL = 1e-5


def test_poses(J=4, seed=1):
    rng = np.random.default_rng(seed)
    axes = rng.normal(size=(J, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    return [np.zeros((J, 3)), axes * 1e-8, axes * 1e-4, axes * (np.pi - 1e-6), axes * np.pi, rng.normal(scale=0.8, size=(J, 3)),
            rng.normal(scale=2.0, size=(J, 3))]


test_poses.__test__ = False  # a helper, not a test


@pytest.mark.parametrize("anisotropic", [False, True], ids=["iso", "aniso"])
@pytest.mark.parametrize("pose_dependent", [True, False], ids=["posedep", "plain"])
@pytest.mark.parametrize("point_colors", [False, True], ids=["triplane-rgb", "point-rgb"])
def test_runtime_gaussians_match_the_torch_model(tmp_path, anisotropic, pose_dependent, point_colors):
    cfg = AvatarConfig(anisotropic=anisotropic, pose_dependent=pose_dependent, point_colors=point_colors, **SMALL)
    model = trained_like(cfg)
    av, info = export_model(model, tmp_path / "a", body_model="test")
    assert av.pose_dependent == pose_dependent and av.anisotropic == anisotropic
    assert (info["onnx_parity_max_abs"] is not None) == pose_dependent
    rng = np.random.default_rng(0)
    worst = {}
    for pose in test_poses():
        pose = pose.astype(np.float32)
        trans = rng.normal(size=3).astype(np.float32)
        with torch.no_grad():
            ref = model(torch.from_numpy(pose), torch.from_numpy(trans)).refined
        got = av.gaussians(pose, trans)
        for name in ("means", "scales", "colors", "opacities"):
            err = float(np.abs(getattr(got, name) - getattr(ref, name).numpy()).max())
            worst[name] = max(worst.get(name, 0.0), err)
        # quaternions up to sign (q and -q are the same rotation; both sides pick w >= 0).
        dq = np.minimum(np.abs(got.quats - ref.quats.numpy()), np.abs(got.quats + ref.quats.numpy())).max()
        worst["quats"] = max(worst.get("quats", 0.0), float(dq))
    assert all(v <= ATOL for v in worst.values()), worst
    if pose_dependent:  # the deltas are really there and really change with the pose
        a, b = (av.gaussians(p.astype(np.float32), np.zeros(3), pose_dependent=flag).colors
                for p, flag in ((test_poses()[5], True), (test_poses()[5], False)))
        assert np.abs(a - b).max() > 1e-3


@pytest.mark.parametrize("level,subdivisions,anisotropic", [(0, 2, False), (1, 2, True), (0, 1, False)])
def test_coarse_pose_avatar_matches_the_torch_model(tmp_path, level, subdivisions, anisotropic):
    """pose_subdivisions: the graph gives the deltas at the coarse level's M vertices (format version 2) and
    the runtime carries them to the Gaussians; the posed Gaussians are the torch model's within the tolerance."""
    cfg = AvatarConfig(subdivisions=subdivisions, pose_subdivisions=level, anisotropic=anisotropic, keep=0.7, **SMALL)
    model = trained_like(cfg, seed=2)
    av, info = export_model(model, tmp_path / "a", body_model="test")
    M, N = model.pose_points.shape[0], model.num_gaussians
    meta = json.loads((tmp_path / "a" / "avatar.json").read_text())
    assert meta["version"] == 2 and meta["pose_points"] == M < N and info["onnx_parity_max_abs"] <= ATOL
    graph = onnx.load(str(tmp_path / "a" / "pose_dependent.onnx")).graph
    assert [o.type.tensor_type.shape.dim[0].dim_value for o in graph.output] == [M] * 3
    rng = np.random.default_rng(1)
    for pose in test_poses():
        pose, trans = pose.astype(np.float32), rng.normal(size=3).astype(np.float32)
        with torch.no_grad():
            out = model(torch.from_numpy(pose), torch.from_numpy(trans))
        for got, want in zip(av.pose_deltas(pose)[::2], (out.delta_offset, out.delta_rgb)):
            assert np.abs(got - want.numpy()).max() <= ATOL
        got = av.gaussians(pose, trans)
        for name in ("means", "scales", "colors"):
            assert np.abs(getattr(got, name) - getattr(out.refined, name).numpy()).max() <= ATOL, name
    # Without the pose-dependent terms the avatar is a version 1 folder.
    plain, _ = export_model(model, tmp_path / "b", body_model="test", pose_dependent=False)
    assert plain.meta["version"] == 1 and "pose_points" not in plain.meta and "pose_indices" not in plain.arrays


def test_default_model_exports_a_version_1_avatar(tmp_path):
    """The pose MLPs at the Gaussians (the default, and every run before pose_subdivisions): version 1, the graph's
    rows are the Gaussians and the runtime adds them as they come."""
    model = trained_like(AvatarConfig(subdivisions=1, **SMALL))
    av, _ = export_model(model, tmp_path / "a", body_model="test")
    meta = json.loads((tmp_path / "a" / "avatar.json").read_text())
    assert meta["version"] == 1 and "pose_points" not in meta and "pose_indices" not in av.arrays
    pose = test_poses()[5].astype(np.float32)
    for got, want in zip(av.pose_deltas(pose), torch_pose_deltas(model, pose)):
        assert got.shape == want.shape == (model.num_gaussians, got.shape[1]) and np.abs(got - want).max() <= ATOL


def test_onnx_graph_matches_the_torch_mlps():
    model = trained_like(AvatarConfig(anisotropic=True, **SMALL), seed=3)
    proto = pose_dependent_onnx(model)
    assert proto.opset_import[0].version == 17
    assert [i.name for i in proto.graph.input] == ["pose"] and [o.name for o in proto.graph.output] == ["d_offset", "d_log_scale", "d_rgb"]
    import onnxruntime as ort

    sess = ort.InferenceSession(proto.SerializeToString(), providers=["CPUExecutionProvider"])
    for pose in [*parity_poses(4, seed=7), *(p.astype(np.float32) for p in test_poses())]:
        got = sess.run(None, {"pose": pose})
        for a, b in zip(got, torch_pose_deltas(model, pose)):
            assert a.shape == b.shape and np.abs(a - b).max() <= ATOL
    assert check_onnx_parity(model, proto) <= ATOL
    # A graph from another model fails the parity check loudly.
    other = trained_like(AvatarConfig(anisotropic=True, **SMALL), seed=4)
    with pytest.raises(ParityError, match=r"pose_dependent.onnx: d_offset: max \|onnxruntime - torch\|"):
        check_onnx_parity(other, proto)


def test_corrupt_or_bad_onnx_is_refused(tmp_path):
    model = trained_like(AvatarConfig(**SMALL))
    export_model(model, tmp_path / "a", body_model="test")
    root = tmp_path / "a"
    onnx_file = root / "pose_dependent.onnx"
    good = onnx_file.read_bytes()
    data = bytearray(good)
    data[len(data) // 2] ^= 0x55
    onnx_file.write_bytes(bytes(data))
    with pytest.raises(FormatError, match=r"pose_dependent.onnx: sha256 .* does not match"):
        load_avatar(root)
    onnx_file.write_bytes(good[: len(good) // 3])
    resign(root, "pose_dependent.onnx")
    with pytest.raises(FormatError, match=r"pose_dependent.onnx: not a loadable ONNX model"):
        load_avatar(root)
    # A valid graph for another skeleton: the input shape is named.
    wrong = GaussianAvatar(grid_mesh(J=3), AvatarConfig(**SMALL))
    onnx_file.write_bytes(pose_dependent_onnx(wrong).SerializeToString())
    resign(root, "pose_dependent.onnx")
    with pytest.raises(FormatError, match=r"pose_dependent.onnx: pose: expected float32 \[4, 3\], got tensor\(float\) \[3, 3\]"):
        load_avatar(root)
    onnx_file.unlink()
    with pytest.raises(FormatError, match="pose_dependent.onnx: missing file"):
        load_avatar(root)


def test_canonical_ply_is_the_rest_pose(tmp_path):
    model = trained_like(AvatarConfig(anisotropic=True, **SMALL))
    av, _ = export_model(model, tmp_path / "a", body_model="test", pose_dependent=False)
    assert not (tmp_path / "a" / "pose_dependent.onnx").exists() and not av.pose_dependent
    with torch.no_grad():
        ref = model(torch.zeros(4, 3), torch.zeros(3)).plain  # exported without the pose-dependent terms
    ply = read_ply(tmp_path / "a" / "canonical.ply")
    for name in ("means", "scales", "colors"):
        np.testing.assert_allclose(getattr(ply, name), getattr(ref, name).numpy(), atol=ATOL, err_msg=name)
    np.testing.assert_allclose(ply.opacities, 1.0, atol=1e-6)


# --------------------------------------------------------------------------------------------------
# the command, end to end on a tiny trained run


def test_export_overwrite_replaces_only_an_avatar_folder_and_never_its_input(tiny_run, tmp_path, capsys):
    run_files = sorted(p.name for p in tiny_run.iterdir())
    thesis = tmp_path / "thesis"
    thesis.mkdir()
    (thesis / "thesis.txt").write_text("mine")
    cases = [(tiny_run, f"{tiny_run}: is the input {tiny_run}"),
             (tiny_run.parent, f"{tiny_run.parent}: holds the input {tiny_run}"),
             (tiny_run / "avatar", f"{tiny_run / 'avatar'}: lies inside the input {tiny_run}"),
             (thesis, f"--overwrite: {thesis / 'thesis.txt'} was not written by trioman (the folder holds no avatar.json")]
    for out, message in cases:
        assert main(["export", "avatar", str(tiny_run), "--out", str(out), "--overwrite"]) == 1
        assert message in capsys.readouterr().err
    assert sorted(p.name for p in tiny_run.iterdir()) == run_files and (thesis / "thesis.txt").read_text() == "mine"


def test_export_command_end_to_end(tiny_run, tmp_path, capsys):
    out = tmp_path / "avatar"
    assert main(["export", "avatar", str(tiny_run), "--out", str(out), "--ply-frame", "1"]) == 0
    printed = capsys.readouterr().out
    assert str(out / "pose_dependent.onnx") in printed and str(out / "posed_1.ply") in printed
    av = load_avatar(out)
    meta = json.loads((out / "avatar.json").read_text())
    assert meta["source"]["step"] == 3 and meta["source"]["run"] == str(tiny_run.resolve()) and meta["body_model"] == "anny"
    assert av.pose_dependent and len(av.pose_joints) > 0
    # The runtime matches the trained torch model at the subject's frames.
    from trioman.toolkit.evaluate import load_run

    model, subject, _, _ = load_run(tiny_run)
    for i in range(subject.num_frames):
        with torch.no_grad():
            ref = model(torch.from_numpy(np.array(subject.poses[i])), torch.from_numpy(np.array(subject.trans[i]))).refined
        got = av.gaussians(subject.poses[i], subject.trans[i])
        for name in ("means", "scales", "colors"):
            assert np.abs(getattr(got, name) - getattr(ref, name).numpy()).max() <= ATOL, name
    posed = read_ply(out / "posed_1.ply")
    np.testing.assert_allclose(posed.means, av.gaussians(subject.poses[1], subject.trans[1]).means, atol=1e-6)
    # Refuses a non-empty --out, replaces it with --overwrite; --no-pose-dependent drops the graph.
    assert main(["export", "avatar", str(tiny_run), "--out", str(out)]) == 1
    assert "--overwrite" in capsys.readouterr().err
    assert main(["export", "avatar", str(tiny_run), "--out", str(out), "--overwrite", "--no-pose-dependent"]) == 0
    assert not load_avatar(out).pose_dependent and not (out / "pose_dependent.onnx").exists()
    assert main(["export", "avatar", str(tiny_run), "--out", str(tmp_path / "b"), "--ply-frame", "99"]) == 1
    assert "--ply-frame: frame 99 out of range" in capsys.readouterr().err and not (tmp_path / "b").exists()
    # The exported folder poses where torch cannot be imported.
    proc = run_python(f"""
        import numpy as np
        from trioman.runtime.formats import load_avatar
        av = load_avatar({str(out)!r})
        g = av.gaussians(np.zeros((av.skeleton.num_joints, 3)), np.zeros(3))
        print(len(g.means))
    """, block_torch=True)
    assert proc.returncode == 0 and proc.stdout.strip() == str(av.num_gaussians), proc.stderr
