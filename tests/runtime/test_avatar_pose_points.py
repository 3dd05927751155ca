"""Avatar format version 2: pose deltas from a graph over M points, carried to the N Gaussians by
``pose_indices``/``pose_weights``; its validation; version 1 avatars pose as before.

The graphs here are built by hand with onnx.helper (no torch); the torch model's own graphs are tested in
tests/export/test_avatar.py.
"""

import json

import numpy as np
import pytest

onnx = pytest.importorskip("onnx")

from onnx import TensorProto, helper, numpy_helper  # noqa: E402

from tests.runtime.factories import edit_json, edit_npz, random_arrays, random_mesh  # noqa: E402
from trioman.runtime.formats import FormatError, load_avatar, save_avatar  # noqa: E402
from trioman.runtime.skeleton import apply_transforms, blend_transforms  # noqa: E402

J, N, M, S = 5, 30, 12, 1


def pose_graph(J: int, rows: int, S: int, seed: int = 0) -> bytes:
    """pose [J, 3] -> d_offset [rows, 3], d_log_scale [rows, S], d_rgb [rows, 3]: a constant per row plus a
    linear function of the pose, so every output changes with the pose."""
    rng = np.random.default_rng(seed)
    C = 3 + S + 3
    inits = [numpy_helper.from_array(np.array([1, 3 * J], np.int64), "shape"),
             numpy_helper.from_array((0.1 * rng.normal(size=(3 * J, C))).astype(np.float32), "W"),
             numpy_helper.from_array((0.1 * rng.normal(size=(rows, C))).astype(np.float32), "base")]
    nodes = [helper.make_node("Reshape", ["pose", "shape"], ["flat"]),
             helper.make_node("MatMul", ["flat", "W"], ["h"]),
             helper.make_node("Add", ["base", "h"], ["all"])]
    outs = []
    for name, lo, hi in (("d_offset", 0, 3), ("d_log_scale", 3, 3 + S), ("d_rgb", 3 + S, C)):
        inits += [numpy_helper.from_array(np.array([lo], np.int64), f"{name}.lo"),
                  numpy_helper.from_array(np.array([hi], np.int64), f"{name}.hi"),
                  numpy_helper.from_array(np.array([1], np.int64), f"{name}.axis")]
        nodes.append(helper.make_node("Slice", ["all", f"{name}.lo", f"{name}.hi", f"{name}.axis"], [name]))
        outs.append(helper.make_tensor_value_info(name, TensorProto.FLOAT, [rows, hi - lo]))
    graph = helper.make_graph(nodes, "test", [helper.make_tensor_value_info("pose", TensorProto.FLOAT, [J, 3])], outs,
                              initializer=inits)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    return model.SerializeToString()


def carry_arrays(seed: int = 0, P: int = 3) -> dict[str, np.ndarray]:
    """pose_indices / pose_weights [N, P]: random convex rows over M points (dyadic weights, as subdivision's)."""
    rng = np.random.default_rng(seed)
    weights = rng.choice([0.25, 0.5, 0.75], size=(N, P))
    weights /= weights.sum(1, keepdims=True)
    return {"pose_indices": rng.integers(0, M, size=(N, P)).astype(np.int32), "pose_weights": weights.astype(np.float32)}


def write_v2(tmp_path, name="a", rows=M, **arrays):
    mesh = random_mesh(1, J=J, V=N)
    gaussians = random_arrays(mesh) | carry_arrays() | arrays
    return save_avatar(tmp_path / name, skeleton=mesh.skeleton, gaussians=gaussians, body_model="test",
                       pose_joints=["j1", "j2"], pose_dependent_onnx=pose_graph(J, rows, S), pose_points=M), gaussians


def test_version_2_round_trip_carries_the_deltas(tmp_path):
    av, arrays = write_v2(tmp_path)
    meta = json.loads((tmp_path / "a" / "avatar.json").read_text())
    assert meta["version"] == 2 and meta["pose_points"] == M
    again = load_avatar(tmp_path / "a")
    assert again.pose_dependent and again.num_gaussians == N
    rng = np.random.default_rng(2)
    pose, trans = rng.normal(size=(J, 3)), rng.normal(size=3)
    coarse = again._session.run(["d_offset", "d_log_scale", "d_rgb"], {"pose": pose.astype(np.float32)})
    assert [d.shape[0] for d in coarse] == [M] * 3
    idx, w = arrays["pose_indices"], arrays["pose_weights"]
    for got, d in zip(again.pose_deltas(pose), coarse):  # by hand: row n = sum_p w[n, p] d[idx[n, p]]
        want = np.stack([sum(w[n, p] * d[idx[n, p]] for p in range(idx.shape[1])) for n in range(N)])
        assert got.shape == want.shape and got.dtype == np.float32
        np.testing.assert_allclose(got, want, atol=1e-6)
    d_off, d_ls, d_rgb = again.pose_deltas(pose)
    A = again.skeleton.skinning_transforms(pose, trans)
    T = blend_transforms(A, arrays["skin_indices"], arrays["skin_weights"])
    g = again.gaussians(pose, trans)
    np.testing.assert_allclose(g.means, apply_transforms(T, (arrays["positions"] + d_off).astype(np.float64)), atol=1e-5)
    np.testing.assert_allclose(g.scales[:, :1], np.exp(arrays["log_scales"] + d_ls), rtol=1e-5)
    np.testing.assert_allclose(g.colors, 1 / (1 + np.exp(-(arrays["rgb_logits"] + d_rgb))), atol=1e-6)


def test_version_1_poses_as_before(tmp_path):
    """A version 1 avatar (no pose_points; the graph's rows are the Gaussians) poses bit for bit as the runtime did
    before version 2: deltas added as the graph gives them, every skinning row blended."""
    mesh = random_mesh(3, J=J, V=N)
    arrays = random_arrays(mesh)
    for key in ("skin_indices", "skin_weights"):  # shared rows, as subdivided Gaussians have
        arrays[key] = np.concatenate([arrays[key][: N // 2]] * 2)
    save_avatar(tmp_path / "a", skeleton=mesh.skeleton, gaussians=arrays, body_model="test", pose_joints=["j1"],
                pose_dependent_onnx=pose_graph(J, N, S, seed=4))
    meta = json.loads((tmp_path / "a" / "avatar.json").read_text())
    assert meta["version"] == 1 and "pose_points" not in meta
    av = load_avatar(tmp_path / "a")
    pose, trans = np.random.default_rng(5).normal(size=(J, 3)), np.array([0.1, -0.2, 0.3])
    d_off, d_ls, d_rgb = av._session.run(["d_offset", "d_log_scale", "d_rgb"], {"pose": pose.astype(np.float32)})
    for got, want in zip(av.pose_deltas(pose), (d_off, d_ls, d_rgb)):
        np.testing.assert_array_equal(got, want)
    a = av.arrays
    T = blend_transforms(av.skeleton.skinning_transforms(pose, trans), a["skin_indices"], a["skin_weights"])
    g = av.gaussians(pose, trans)
    np.testing.assert_array_equal(g.means, apply_transforms(T, (a["positions"] + d_off).astype(np.float64)).astype(np.float32))
    scales = np.exp(np.clip((a["log_scales"] + d_ls).astype(np.float64), -12.0, 2.0))
    np.testing.assert_array_equal(g.scales, np.broadcast_to(scales, (N, 3)).astype(np.float32))
    np.testing.assert_array_equal(g.colors, (0.5 * (1 + np.tanh(0.5 * (a["rgb_logits"] + d_rgb).astype(np.float64)))).astype(np.float32))


def _meta(root):
    return json.loads((root / "avatar.json").read_text())


V2_CASES = [
    ("no pose_points", lambda r: edit_json(r, pose_points=None),
     r"avatar.json: pose_points: expected a positive integer \(the pose-dependent graph's rows\), got None"),
    ("zero pose_points", lambda r: edit_json(r, pose_points=0), r"avatar.json: pose_points: expected a positive integer.*got 0"),
    ("text pose_points", lambda r: edit_json(r, pose_points="12"), r"avatar.json: pose_points: expected a positive integer.*got '12'"),
    ("bool pose_points", lambda r: edit_json(r, pose_points=True), r"avatar.json: pose_points: expected a positive integer.*got True"),
    ("pose_points in version 1", lambda r: edit_json(r, version=1), r"avatar.json: pose_points: not a version 1 field \(version 2 adds it\)"),
    ("without pose dependence", lambda r: edit_json(r, pose_dependent=False, files={
        k: v for k, v in _meta(r)["files"].items() if k != "pose_dependent.onnx"}),
     r"avatar.json: pose_points: given, but pose_dependent is false"),
    ("graph rows", lambda r: edit_json(r, pose_points=M + 1),
     rf"pose_dependent.onnx: d_offset: expected float32 \[{M + 1}, 3\], got float32 \[{M}, 3\]"),
    ("missing indices", lambda r: edit_npz(r, "gaussians.npz", pose_indices=None), r"gaussians.npz: pose_indices: missing array"),
    ("index range", lambda r: edit_npz(r, "gaussians.npz", pose_indices=np.full((N, 3), M, np.int32)),
     rf"gaussians.npz: pose_indices: pose point indices must lie in \[0, {M}\) \(avatar.json pose_points\), got \[{M}, {M}\]"),
    ("float indices", lambda r: edit_npz(r, "gaussians.npz", pose_indices=np.zeros((N, 3), np.float32)),
     r"gaussians.npz: pose_indices: expected integers, got dtype float32"),
    ("row count", lambda r: edit_npz(r, "gaussians.npz", pose_weights=np.full((N - 1, 3), 1 / 3, np.float32)),
     rf"gaussians.npz: pose_weights: {N - 1} Gaussians, but avatar.json num_gaussians is {N}"),
    ("shapes differ", lambda r: edit_npz(r, "gaussians.npz", pose_weights=np.full((N, 2), 0.5, np.float32)),
     r"gaussians.npz: pose_weights: shape \[30, 2\] differs from pose_indices \[30, 3\]"),
    ("row sums", lambda r: edit_npz(r, "gaussians.npz", pose_weights=np.full((N, 3), 0.5, np.float32)),
     r"gaussians.npz: pose_weights: rows must sum to 1, Gaussian 0 sums to 1.500000"),
    ("negative", lambda r: edit_npz(r, "gaussians.npz", pose_weights=np.tile(np.float32([1.5, -0.5, 0.0]), (N, 1))),
     r"gaussians.npz: pose_weights: 30 negative weight\(s\)"),
    ("nan", lambda r: edit_npz(r, "gaussians.npz", pose_weights=np.full((N, 3), np.nan, np.float32)),
     r"gaussians.npz: pose_weights: 90 non-finite value\(s\)"),
]


@pytest.mark.parametrize("case,damage,message", V2_CASES, ids=[c[0] for c in V2_CASES])
def test_version_2_validation_errors(tmp_path, case, damage, message):
    write_v2(tmp_path)
    damage(tmp_path / "a")
    with pytest.raises(FormatError, match=message):
        load_avatar(tmp_path / "a")


def test_carry_arrays_in_a_version_1_avatar_are_refused(tmp_path):
    mesh = random_mesh(1, J=J, V=N)
    save_avatar(tmp_path / "a", skeleton=mesh.skeleton, gaussians=random_arrays(mesh), body_model="test")
    edit_npz(tmp_path / "a", "gaussians.npz", **carry_arrays())
    with pytest.raises(FormatError, match=r"gaussians.npz: pose_indices: present, but avatar.json has no pose_points"):
        load_avatar(tmp_path / "a")
    with pytest.raises(FormatError, match=r"save_avatar: pose_indices: present, but avatar.json has no pose_points"):
        save_avatar(tmp_path / "b", skeleton=mesh.skeleton, gaussians=random_arrays(mesh) | carry_arrays(), body_model="test")
    assert not (tmp_path / "b").exists()


def test_save_validates_the_version_2_fields(tmp_path):
    with pytest.raises(FormatError, match=rf"save_avatar: pose_dependent.onnx: d_offset: expected float32 \[{M}, 3\], got float32 \[{N}, 3\]"):
        write_v2(tmp_path, rows=N)
    mesh = random_mesh(1, J=J, V=N)
    with pytest.raises(FormatError, match=r"save_avatar: pose_points: given, but pose_dependent is false"):
        save_avatar(tmp_path / "a", skeleton=mesh.skeleton, gaussians=random_arrays(mesh) | carry_arrays(),
                    body_model="test", pose_points=M)
    with pytest.raises(FormatError, match=r"save_avatar: pose_indices: missing array"):
        save_avatar(tmp_path / "a", skeleton=mesh.skeleton, gaussians=random_arrays(mesh), body_model="test",
                    pose_joints=["j1"], pose_dependent_onnx=pose_graph(J, M, S), pose_points=M)
    assert not list(tmp_path.iterdir())
