"""SMPL-X body model: numpy FK + LBS (runtime) against smplx's own forward, on the fake model file."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")
smplx = pytest.importorskip("smplx", reason="needs the 'smplx' extra: pip install 'trioman[smplx]'")

from trioman.runtime.formats import FormatError  # noqa: E402
from trioman.toolkit.body.registry import create_body_model  # noqa: E402
from trioman.toolkit.body.smplx_model import (  # noqa: E402
    NUM_FACES, NUM_JOINTS, NUM_VERTICES, Y_UP_TO_Z_UP, SMPLXBody, full_pose, to_z_up,
)
from tests.toolkit.body.fake_smplx import write_fake_smplx  # noqa: E402

NUM_BETAS = 100  # ExAvatar's setting


@pytest.fixture(scope="module")
def betas():
    return np.random.default_rng(3).normal(size=NUM_BETAS)


@pytest.fixture(scope="module")
def body(smplx_model_dir, betas):
    return create_body_model("smplx", model_dir=smplx_model_dir, gender="male", num_betas=NUM_BETAS, betas=betas)


@pytest.fixture(scope="module")
def reference(smplx_model_dir):
    """smplx's own layer on the same file, float64, ExAvatar's settings (no hand PCA, hand mean on)."""
    return smplx.SMPLX(str(smplx_model_dir), gender="male", num_betas=NUM_BETAS, use_pca=False,
                       flat_hand_mean=False, num_expression_coeffs=10, dtype=torch.float64)


def random_params(seed: int, n: int = 5) -> dict[str, np.ndarray]:
    """SMPL-X parameters as a fitter gives them; frame 3 has every joint near pi, frame 4 tiny angles."""
    rng = np.random.default_rng(seed)
    p = {"root": rng.normal(scale=0.8, size=(n, 3)), "body": rng.normal(scale=0.5, size=(n, 21, 3)),
         "jaw": rng.normal(scale=0.2, size=(n, 3)), "leye": rng.normal(scale=0.2, size=(n, 3)),
         "reye": rng.normal(scale=0.2, size=(n, 3)), "lhand": rng.normal(scale=0.4, size=(n, 15, 3)),
         "rhand": rng.normal(scale=0.4, size=(n, 15, 3)), "transl": rng.normal(size=(n, 3))}
    for key, size in (("root", None), ("jaw", None), ("leye", None), ("reye", None), ("body", 21), ("lhand", 15), ("rhand", 15)):
        shape = (3,) if size is None else (size, 3)
        axes = rng.normal(size=shape)
        axes /= np.linalg.norm(axes, axis=-1, keepdims=True)
        p[key][3] = axes * (np.pi - 1e-6)
        p[key][4] = axes * 1e-9
    return p


def smplx_vertices(reference, params, betas) -> np.ndarray:
    t = {k: torch.from_numpy(np.asarray(v, dtype=np.float64)) for k, v in params.items()}
    n = len(params["root"])
    out = reference(betas=torch.from_numpy(betas)[None].expand(n, -1), global_orient=t["root"],
                    body_pose=t["body"].reshape(n, -1), jaw_pose=t["jaw"], leye_pose=t["leye"], reye_pose=t["reye"],
                    left_hand_pose=t["lhand"].reshape(n, -1), right_hand_pose=t["rhand"].reshape(n, -1),
                    transl=t["transl"], expression=torch.zeros(n, 10, dtype=torch.float64))
    return out.vertices.numpy(), out.joints[:, :NUM_JOINTS].numpy()


def test_sizes_and_interface(body):
    mesh = body.to_skinned_mesh()
    assert mesh.num_vertices == NUM_VERTICES and len(mesh.faces) == NUM_FACES
    assert mesh.skeleton.num_joints == NUM_JOINTS
    assert mesh.skeleton.joint_names[22:25] == ("jaw", "left_eye", "right_eye")
    assert mesh.pose_correctives.shape == (9 * 54, NUM_VERTICES, 3)
    assert mesh.uvs is not None and mesh.uv_faces.shape == mesh.faces.shape


def test_numpy_runtime_matches_smplx_forward(body, reference, betas):
    """Within 1e-5 m on random poses, every joint near pi and tiny angles included."""
    mesh = body.to_skinned_mesh()
    params = random_params(0)
    want_v, want_j = smplx_vertices(reference, params, betas)
    pose = full_pose(body.hand_mean.numpy(), *(params[k] for k in ("root", "body", "jaw", "leye", "reye", "lhand", "rhand")))
    trans = to_z_up(params["transl"])
    got_v = mesh.pose(pose, trans) @ Y_UP_TO_Z_UP  # back to SMPL-X's frame
    err = np.abs(got_v - want_v).max(axis=(1, 2))
    assert err.max() <= 1e-5, f"max vertex error per frame {err} m"
    got_j = mesh.skeleton.forward_kinematics(pose, trans)[:, :, :3, 3] @ Y_UP_TO_Z_UP
    assert np.abs(got_j - want_j).max() <= 1e-5
    torch_v = body(torch.from_numpy(pose), torch.from_numpy(trans)).vertices.double().numpy() @ Y_UP_TO_Z_UP
    assert np.abs(torch_v - want_v).max() <= 1e-5


def test_flat_hand_mean_and_zero_pose(smplx_model_dir):
    flat = SMPLXBody(smplx_model_dir, gender="neutral", num_betas=10, flat_hand_mean=True, dtype=torch.float64)
    assert float(flat.hand_mean.abs().max()) == 0.0
    out = flat(torch.zeros(1, NUM_JOINTS, 3, dtype=torch.float64), torch.zeros(1, 3, dtype=torch.float64))
    np.testing.assert_allclose(out.vertices[0].numpy(), flat.canonical_vertices.numpy(), atol=1e-12)


def test_joint_offset_moves_joints_but_not_the_pelvis(smplx_model_dir):
    offset = np.full((NUM_JOINTS, 3), 0.01)
    plain = SMPLXBody(smplx_model_dir, dtype=torch.float64)
    moved = SMPLXBody(smplx_model_dir, joint_offset=offset, dtype=torch.float64)
    d = (moved.rest_joints - plain.rest_joints).numpy()
    np.testing.assert_allclose(d[0], 0.0, atol=1e-12)
    np.testing.assert_allclose(d[1:], np.tile(to_z_up(offset[0]), (NUM_JOINTS - 1, 1)), atol=1e-12)


def test_missing_model_file_is_one_line_naming_file_place_and_licence(tmp_path):
    with pytest.raises(FileNotFoundError) as err:
        SMPLXBody(tmp_path, gender="female")
    msg = str(err.value)
    assert "\n" not in msg and "SMPLX_FEMALE.npz" in msg and str(tmp_path) in msg and "licensed" in msg


def test_bad_model_files_and_settings(smplx_model_dir, tmp_path):
    with pytest.raises(ValueError, match="gender: unknown gender 'other'"):
        SMPLXBody(smplx_model_dir, gender="other")
    with pytest.raises(ValueError, match="num_betas: 400 requested"):
        SMPLXBody(smplx_model_dir, num_betas=400)
    arrays = dict(np.load(smplx_model_dir / "SMPLX_MALE.npz", allow_pickle=True))
    del arrays["posedirs"]
    np.savez(tmp_path / "SMPLX_NEUTRAL.npz", **arrays)
    with pytest.raises(FormatError, match=r"SMPLX_NEUTRAL.npz: posedirs: missing array"):
        SMPLXBody(tmp_path)


def test_fixture_keeps_the_real_sizes(tmp_path):
    path = write_fake_smplx(tmp_path / "SMPLX_MALE.npz", seed=1)
    with np.load(path, allow_pickle=False) as f:
        assert f["v_template"].shape == (NUM_VERTICES, 3) and f["f"].shape == (NUM_FACES, 3)
        assert f["J_regressor"].shape == (NUM_JOINTS, NUM_VERTICES)
        np.testing.assert_allclose(f["weights"].sum(1), 1.0)
