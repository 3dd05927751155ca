"""The avatar format without torch: round trip, validation errors, numpy posing, .ply files.

Avatars here are random arrays (no ONNX graph); the pose-dependent graph and parity with the torch
model are tested in tests/export/test_avatar.py.
"""

import json
import shutil

import numpy as np
import pytest

from tests.conftest import run_python
from tests.runtime.factories import edit_json, edit_npz, random_arrays, random_mesh, resign, write
from trioman.runtime.avatar import Avatar, Gaussians
from trioman.runtime.formats import FormatError, load_avatar, save_avatar
from trioman.runtime.ply import read_ply, write_ply
from trioman.runtime.rotations import axis_angle_to_matrix, matrix_to_quat
from trioman.runtime.skeleton import blend_transforms


@pytest.mark.parametrize("anisotropic", [False, True])
def test_round_trip_and_posing_by_hand(tmp_path, anisotropic):
    av, mesh = write(tmp_path, anisotropic, posed={"7": (np.full((5, 3), 0.2), np.ones(3))})
    again = load_avatar(tmp_path / "a")
    assert isinstance(again, Avatar) and again.num_gaussians == 30 and again.anisotropic == anisotropic
    assert not again.pose_dependent and again.pose_joints == ("j1", "j2")
    assert again.meta["source"] == {"run": "nowhere", "step": 3} and again.meta["body_model"] == "test"
    assert sorted(again.meta["files"]) == ["canonical.ply", "gaussians.npz", "posed_7.ply", "skeleton.npz"]
    assert not list(tmp_path.glob(".*")), "no temporary folder left"
    rng = np.random.default_rng(3)
    pose, trans = rng.normal(size=(5, 3)), rng.normal(size=3)
    g = again.gaussians(pose, trans)
    assert all(isinstance(a, np.ndarray) and a.dtype == np.float32 for a in g)
    a = random_arrays(mesh, anisotropic)
    # The same thing written out with a dense LBS, per Gaussian.
    A = mesh.skeleton.skinning_transforms(pose, trans)
    W = mesh.dense_weights()
    T = np.einsum("nj,jab->nab", W, A)[:, :3]
    np.testing.assert_allclose(g.means, np.einsum("nab,nb->na", T[:, :, :3], a["positions"]) + T[:, :, 3], atol=1e-5)
    np.testing.assert_allclose(g.scales, np.broadcast_to(np.exp(a["log_scales"]), (30, 3)), rtol=1e-6)
    np.testing.assert_allclose(g.colors, 1 / (1 + np.exp(-a["rgb_logits"])), atol=1e-6)
    if anisotropic:
        from trioman.runtime.rotations import quat_to_matrix

        np.testing.assert_allclose(g.quats, matrix_to_quat(T[:, :, :3] @ quat_to_matrix(a["local_quats"])), atol=1e-6)
    else:
        assert np.all(g.quats == np.array([1, 0, 0, 0], np.float32))
    # canonical.ply is the rest pose, posed_7.ply the given pose.
    rest = read_ply(tmp_path / "a" / "canonical.ply")
    np.testing.assert_allclose(rest.means, a["positions"], atol=1e-6)
    posed = read_ply(tmp_path / "a" / "posed_7.ply")
    for x, y in zip(posed, again.gaussians(np.full((5, 3), 0.2), np.ones(3))):
        np.testing.assert_allclose(x, y, atol=1e-6)


def test_blend_transforms_is_the_dense_blend():
    mesh = random_mesh(4, J=6, V=20, K=4)
    A = mesh.skeleton.skinning_transforms(np.random.default_rng(0).normal(size=(2, 6, 3)), np.zeros((2, 3)))
    T = blend_transforms(A, mesh.skin_indices, mesh.skin_weights)
    np.testing.assert_allclose(T, np.einsum("nj,bjak->bnak", mesh.dense_weights(), A[:, :, :3]), atol=1e-12)
    assert T.shape == (2, 20, 3, 4)


def test_matrix_to_quat_of_a_blend_is_normalised():
    R = 0.5 * (axis_angle_to_matrix(np.array([0.0, 0.0, 3.0])) + axis_angle_to_matrix(np.array([0.0, 0.0, -3.0])))
    q = matrix_to_quat(R)  # a non-orthonormal blend
    np.testing.assert_allclose(np.linalg.norm(q), 1.0, atol=1e-12)
    assert np.all(np.isfinite(matrix_to_quat(np.zeros((3, 3)))))  # no 0/0: the norm is clamped


def test_refuses_to_overwrite_and_bad_pose(tmp_path):
    av, _ = write(tmp_path)
    with pytest.raises(FileExistsError, match="not empty"):
        write(tmp_path)
    write(tmp_path, overwrite=True)
    (tmp_path / "a" / "thesis.txt").write_text("mine")  # a file of the user's: the folder is no longer replaced
    with pytest.raises(FileExistsError, match=r"^overwrite: .*thesis.txt was not written by trioman"):
        write(tmp_path, overwrite=True)
    assert (tmp_path / "a" / "thesis.txt").is_file() and (tmp_path / "a" / "avatar.json").is_file()
    with pytest.raises(ValueError, match=r"pose: expected shape \[\.\.\., 5, 3\]"):
        av.gaussians(np.zeros((4, 3)), np.zeros(3))
    pose = np.zeros((5, 3))
    pose[2, 1] = np.nan
    with pytest.raises(ValueError, match=r"pose: 1 non-finite"):
        av.gaussians(pose, np.zeros(3))
    with pytest.raises(ValueError, match="pose_dependent"):
        av.pose_deltas(np.zeros((5, 3)))


# --------------------------------------------------------------------------------------------------
# validation: every problem is a FormatError naming the file and the field


def _corrupt(root, name):
    data = bytearray((root / name).read_bytes())
    data[len(data) // 2] ^= 0xFF
    (root / name).write_bytes(bytes(data))


CASES = [
    ("missing folder", lambda r: shutil.rmtree(r), r"avatar folder not found"),
    ("missing json", lambda r: (r / "avatar.json").unlink(), r"avatar.json: missing file"),
    ("missing npz", lambda r: (r / "gaussians.npz").unlink(), r"gaussians.npz: missing file"),
    ("truncated npz", lambda r: (r / "gaussians.npz").write_bytes((r / "gaussians.npz").read_bytes()[:100]),
     r"gaussians.npz: \d+ bytes, but avatar.json lists \d+ \(truncated"),
    ("corrupt npz", lambda r: _corrupt(r, "gaussians.npz"), r"gaussians.npz: sha256 .* does not match"),
    ("corrupt ply", lambda r: _corrupt(r, "canonical.ply"), r"canonical.ply: sha256"),
    ("truncated and resigned npz", lambda r: ((r / "gaussians.npz").write_bytes((r / "gaussians.npz").read_bytes()[:300]),
                                              resign(r, "gaussians.npz")), r"gaussians.npz: not a valid .npz"),
    ("format", lambda r: edit_json(r, format="trioman-subject"), r"avatar.json: format: expected 'trioman-avatar'"),
    ("version", lambda r: edit_json(r, version=3), r"avatar.json: version: unknown version 3"),
    ("units", lambda r: edit_json(r, units="cm"), r"avatar.json: units"),
    ("no body model", lambda r: edit_json(r, body_model=None), r"avatar.json: body_model: missing field"),
    ("clamp", lambda r: edit_json(r, scale_clamp=[-10, 2]), r"avatar.json: scale_clamp"),
    ("count", lambda r: edit_json(r, num_gaussians=31), r"gaussians.npz: positions: 30 Gaussians, but avatar.json num_gaussians is 31"),
    ("pose joints", lambda r: edit_json(r, pose_joints=["j1", "elbow"]), r"avatar.json: pose_joints: unknown joint name\(s\) \['elbow'\]"),
    ("onnx listed", lambda r: edit_json(r, pose_dependent=True), r"avatar.json: files.pose_dependent.onnx: missing entry"),
    ("stray file", lambda r: edit_json(r, files={**json.loads((r / "avatar.json").read_text())["files"], "evil.sh": {"sha256": "0" * 64, "bytes": 1}}),
     r"files.evil.sh: unexpected file name"),
    ("nan", lambda r: edit_npz(r, "gaussians.npz", rgb_logits=np.full((30, 3), np.nan, np.float32)),
     r"gaussians.npz: rgb_logits: 90 non-finite value\(s\)"),
    ("missing field", lambda r: edit_npz(r, "gaussians.npz", log_scales=None), r"gaussians.npz: log_scales: missing array"),
    ("wrong shape", lambda r: edit_npz(r, "gaussians.npz", log_scales=np.zeros((30, 3), np.float32)),
     r"gaussians.npz: log_scales: expected shape \[30, 1\], got \[30, 3\]"),
    ("weights", lambda r: edit_npz(r, "gaussians.npz", skin_weights=np.full((30, 3), 0.5, np.float32)),
     r"gaussians.npz: skin_weights: rows must sum to 1"),
    ("joint index", lambda r: edit_npz(r, "gaussians.npz", skin_indices=np.full((30, 3), 9, np.int32)),
     r"gaussians.npz: skin_indices: joint indices must lie in \[0, 5\)"),
    ("aniso mismatch", lambda r: edit_npz(r, "gaussians.npz", local_quats=np.ones((30, 4), np.float32)),
     r"gaussians.npz: local_quats: present, but avatar.json says the avatar is isotropic"),
    ("pickle", lambda r: ((np.save(open(r / "skeleton.npz", "wb"), np.array([{}], dtype=object), allow_pickle=True)), resign(r, "skeleton.npz")),
     r"skeleton.npz: a single .npy array|skeleton.npz: not a valid"),
    ("skeleton parents", lambda r: edit_npz(r, "skeleton.npz", parents=np.array([-1, 0, 5, 1, 2])),
     r"skeleton.npz: parents"),
]


@pytest.mark.parametrize("case,damage,message", CASES, ids=[c[0] for c in CASES])
def test_validation_errors(tmp_path, case, damage, message):
    write(tmp_path)
    damage(tmp_path / "a")
    with pytest.raises(FormatError, match=message):
        load_avatar(tmp_path / "a")


def test_save_validates_before_writing(tmp_path):
    mesh = random_mesh(1, J=5, V=30)
    bad = random_arrays(mesh)
    bad["positions"][3, 1] = np.inf
    with pytest.raises(FormatError, match=r"save_avatar: positions: 1 non-finite value\(s\) \(NaN/Inf\), first at Gaussian 3"):
        save_avatar(tmp_path / "a", skeleton=mesh.skeleton, gaussians=bad, body_model="test")
    with pytest.raises(FormatError, match="save_avatar: pose_dependent.onnx: not a loadable ONNX model"):
        save_avatar(tmp_path / "a", skeleton=mesh.skeleton, gaussians=random_arrays(mesh), body_model="test",
                    pose_joints=["j1"], pose_dependent_onnx=b"not onnx")
    assert not (tmp_path / "a").exists() and not list(tmp_path.iterdir())


# --------------------------------------------------------------------------------------------------
# .ply


def random_gaussians(N=50, seed=0):
    rng = np.random.default_rng(seed)
    q = rng.normal(size=(N, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return Gaussians(rng.normal(size=(N, 3)).astype(np.float32), q.astype(np.float32),
                     np.exp(rng.uniform(-7, 1, size=(N, 3))).astype(np.float32),
                     np.concatenate([[0.0, 1.0], rng.random(N - 2)]).astype(np.float32),
                     rng.random((N, 3)).astype(np.float32))


def test_ply_round_trip_and_layout(tmp_path):
    g = random_gaussians()
    write_ply(tmp_path / "g.ply", *g)
    back = read_ply(tmp_path / "g.ply")
    for name, a, b in zip(Gaussians._fields, g, back):
        np.testing.assert_allclose(b, a, atol=1e-6, rtol=1e-6, err_msg=name)
    raw = (tmp_path / "g.ply").read_bytes()
    header = raw[: raw.index(b"end_header\n")].decode().splitlines()
    assert header[:3] == ["ply", "format binary_little_endian 1.0", "element vertex 50"]
    assert [h.split()[2] for h in header[3:]] == ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity",
                                                  "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    data = np.frombuffer(raw[raw.index(b"end_header\n") + 11:], "<f4").reshape(50, 14)
    np.testing.assert_allclose(data[:, 3:6], (g.colors - 0.5) / 0.28209479177387814, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(data[:, 7:10], np.log(g.scales), rtol=1e-6, atol=1e-6)
    assert np.all(np.isfinite(data))  # opacity 0 and 1 clipped to finite logits


def test_ply_reads_extra_properties_and_rejects_bad_files(tmp_path):
    g = random_gaussians(4)
    write_ply(tmp_path / "g.ply", *g)
    raw = (tmp_path / "g.ply").read_bytes()
    body = raw[raw.index(b"end_header\n") + 11:]
    # An INRIA-style file with normals in front.
    names = ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1", "scale_2",
             "rot_0", "rot_1", "rot_2", "rot_3"]
    rows = np.frombuffer(body, "<f4").reshape(4, 14)
    withn = np.concatenate([rows[:, :3], np.zeros((4, 3), np.float32), rows[:, 3:]], 1)
    head = "ply\nformat binary_little_endian 1.0\ncomment x\nelement vertex 4\n" + "".join(f"property float {n}\n" for n in names) + "end_header\n"
    (tmp_path / "n.ply").write_bytes(head.encode() + withn.tobytes())
    for a, b in zip(read_ply(tmp_path / "g.ply"), read_ply(tmp_path / "n.ply")):
        np.testing.assert_array_equal(a, b)
    (tmp_path / "t.ply").write_bytes(raw[:-5])
    with pytest.raises(FormatError, match=r"t.ply: truncated: 4 vertices need 224 bytes"):
        read_ply(tmp_path / "t.ply")
    (tmp_path / "m.ply").write_bytes(raw.replace(b"property float opacity\n", b"").replace(body, body[: 4 * 13 * 4]))
    with pytest.raises(FormatError, match=r"m.ply: vertex: missing property \['opacity'\]"):
        read_ply(tmp_path / "m.ply")
    (tmp_path / "a.ply").write_bytes(raw.replace(b"binary_little_endian", b"ascii"))
    with pytest.raises(FormatError, match="a.ply: format: expected 'binary_little_endian 1.0'"):
        read_ply(tmp_path / "a.ply")
    (tmp_path / "x.ply").write_bytes(b"PK\x03\x04 not a ply")
    with pytest.raises(FormatError, match="x.ply: not a PLY file"):
        read_ply(tmp_path / "x.ply")
    with pytest.raises(FormatError, match="nothing.ply: missing file"):
        read_ply(tmp_path / "nothing.ply")
    with pytest.raises(ValueError, match="scales: expected shape \\[4, 3\\]"):
        write_ply(tmp_path / "w.ply", g.means, g.quats, g.scales[:3], g.opacities, g.colors)


def test_load_and_pose_without_torch(tmp_path):
    write(tmp_path, anisotropic=True)
    proc = run_python(f"""
        import numpy as np
        from trioman.runtime.formats import load_avatar
        av = load_avatar({str(tmp_path / 'a')!r})
        g = av.gaussians(np.full((5, 3), 0.3), np.zeros(3))
        assert g.means.shape == (30, 3) and np.isfinite(g.means).all()
        import sys; assert 'torch' not in sys.modules or sys.modules['torch'] is None
        print("ok")
    """, block_torch=True)
    assert proc.returncode == 0 and "ok" in proc.stdout, proc.stderr
