"""SMPL-X (Pavlakos et al. 2019) behind the body-model interface, built with the ``smplx`` package from the
user's licensed model file (never shipped, read without pickle).

The file, the settings, the y-up -> z-up turn (``Y_UP_TO_Z_UP``), the full pose with the hand means
(:func:`full_pose`) and what is baked into the rest mesh: docs/real_data.md, "The SMPL-X body" and
"Frames and axes".
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from trioman.runtime.formats import FormatError
from trioman.toolkit.body.base import BodyModel, BodyOutput
from trioman.toolkit.body.skinning import apply_transforms, blend_transforms, skinning_transforms
from trioman.toolkit.rotations import axis_angle_to_matrix

GENDERS = ("neutral", "male", "female")
NUM_VERTICES = 10475
NUM_FACES = 20908
NUM_JOINTS = 55
NUM_BODY_JOINTS = 21  # without the pelvis
NUM_HAND_JOINTS = 15
SMPLX_URL = "https://smpl-x.is.tue.mpg.de"
Y_UP_TO_Z_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # M: SMPL-X frame -> TrioMan world

JOINT_NAMES = (
    "pelvis", "left_hip", "right_hip", "spine1", "left_knee", "right_knee", "spine2", "left_ankle", "right_ankle",
    "spine3", "left_foot", "right_foot", "neck", "left_collar", "right_collar", "head", "left_shoulder",
    "right_shoulder", "left_elbow", "right_elbow", "left_wrist", "right_wrist", "jaw", "left_eye", "right_eye",
    *(f"{side}_{finger}{k}" for side in ("left", "right") for finger in ("index", "middle", "pinky", "ring", "thumb")
      for k in (1, 2, 3)),
)

# The arrays smplx reads from the file (use_face_contour=False), with their shapes (None: any size).
_KEYS = {
    "v_template": (NUM_VERTICES, 3),
    "f": (NUM_FACES, 3),
    "J_regressor": (NUM_JOINTS, NUM_VERTICES),
    "weights": (NUM_VERTICES, NUM_JOINTS),
    "kintree_table": (2, NUM_JOINTS),
    "shapedirs": (NUM_VERTICES, 3, None),
    "posedirs": (NUM_VERTICES, 3, 9 * (NUM_JOINTS - 1)),
    "hands_meanl": (3 * NUM_HAND_JOINTS,),
    "hands_meanr": (3 * NUM_HAND_JOINTS,),
    "hands_componentsl": (3 * NUM_HAND_JOINTS, 3 * NUM_HAND_JOINTS),
    "hands_componentsr": (3 * NUM_HAND_JOINTS, 3 * NUM_HAND_JOINTS),
    "lmk_faces_idx": (None,),
    "lmk_bary_coords": (None, 3),
}
_UV_KEYS = {"vt": (None, 2), "ft": (NUM_FACES, 3)}  # optional texture coordinates


def model_file(model_dir: str | Path, gender: str) -> Path:
    """The SMPL-X file of ``gender`` in ``model_dir`` (or its ``smplx/`` folder). A one-line FileNotFoundError
    names the file, where it belongs and that it is licensed when it is missing."""
    check_gender(gender)
    name = f"SMPLX_{gender.upper()}.npz"
    model_dir = Path(model_dir)
    for candidate in (model_dir / name, model_dir / "smplx" / name):
        if candidate.is_file():
            return candidate
    raise FileNotFoundError(
        f"{model_dir / name}: SMPL-X model file not found; SMPL-X is licensed and not shipped: register at "
        f"{SMPLX_URL}, download the SMPL-X npz models and put {name} in {model_dir} (`model_dir`)")


def check_gender(gender: str) -> str:
    if gender not in GENDERS:
        raise ValueError(f"gender: unknown gender {gender!r}; expected one of {list(GENDERS)}")
    return gender


def _check_array(path: Path, key: str, a: np.ndarray, shape: tuple) -> None:
    if a.ndim != len(shape) or any(s is not None and n != s for n, s in zip(a.shape, shape)):
        want = "[" + ", ".join("*" if s is None else str(s) for s in shape) + "]"
        raise FormatError(f"{path}: {key}: expected shape {want}, got {list(a.shape)}")
    if a.dtype.kind == "f" and not np.isfinite(a).all():
        raise FormatError(f"{path}: {key}: {int((~np.isfinite(a)).sum())} non-finite value(s) (NaN/Inf)")
    if a.dtype.kind not in "fiu":
        raise FormatError(f"{path}: {key}: expected numbers, got dtype {a.dtype}")


def load_model_arrays(path: str | Path) -> dict[str, np.ndarray]:
    """The arrays smplx needs from an SMPL-X .npz, read without pickle and checked (keys, shapes, finite)."""
    path = Path(path)
    try:
        archive = np.load(path, allow_pickle=False)
    except Exception as err:  # numpy raises several types for a file that is not an npz
        raise FormatError(f"{path}: not a valid .npz archive ({type(err).__name__}: {err})") from None
    if not isinstance(archive, np.lib.npyio.NpzFile):
        raise FormatError(f"{path}: a single .npy array, not an SMPL-X .npz archive")
    with archive:
        arrays = {}
        for key, shape in {**_KEYS, **_UV_KEYS}.items():
            if key not in archive.files:
                if key in _UV_KEYS:
                    continue
                raise FormatError(f"{path}: {key}: missing array (not an SMPL-X model file?)")
            try:
                arrays[key] = archive[key]
            except ValueError as err:
                raise FormatError(f"{path}: {key}: unreadable without pickle ({err})") from None
            _check_array(path, key, arrays[key], shape)
    if ("vt" in arrays) != ("ft" in arrays):
        arrays.pop("vt", None), arrays.pop("ft", None)
    if int(arrays["f"].max()) >= NUM_VERTICES:
        raise FormatError(f"{path}: f: vertex index {int(arrays['f'].max())} out of range [0, {NUM_VERTICES})")
    return arrays


def shape_coefficients(arrays: dict[str, np.ndarray]) -> int:
    """How many shape coefficients (betas) a model file holds, as smplx counts them (300 or 10)."""
    return 300 if arrays["shapedirs"].shape[-1] >= 400 else 10


def to_z_up(points: np.ndarray) -> np.ndarray:
    """Points or axis-angles [..., 3] from SMPL-X's frame (y up) to TrioMan's world (z up)."""
    return np.asarray(points) @ Y_UP_TO_Z_UP.T


def viewmat_to_z_up(viewmat: np.ndarray) -> np.ndarray:
    """World -> camera [..., 4, 4] of a y-up world to the z-up world: viewmat diag(M^T, 1)."""
    M = np.eye(4)
    M[:3, :3] = Y_UP_TO_Z_UP.T
    return np.asarray(viewmat) @ M


def full_pose(hand_mean: np.ndarray, root: np.ndarray, body: np.ndarray, jaw: np.ndarray, leye: np.ndarray,
              reye: np.ndarray, lhand: np.ndarray, rhand: np.ndarray) -> np.ndarray:
    """SMPL-X parameters (axis-angle, SMPL-X frame, hands relative to their mean) -> [N, 55, 3] full pose
    in TrioMan's world. root, jaw, leye, reye: [N, 3]; body: [N, 21, 3]; hands: [N, 15, 3];
    hand_mean: [30, 3] (zeros for flat_hand_mean)."""
    pose = np.concatenate([np.asarray(root)[:, None], body, np.asarray(jaw)[:, None], np.asarray(leye)[:, None],
                           np.asarray(reye)[:, None], lhand, rhand], axis=1).astype(np.float64)
    pose[:, 25:] += hand_mean
    return to_z_up(pose)


@dataclass(frozen=True)
class SMPLXConfig:
    """How to build the body: the model folder and smplx's layer settings (ExAvatar: male, 100 betas)."""

    model_dir: str
    gender: str = "neutral"
    num_betas: int = 10
    flat_hand_mean: bool = False


class SMPLXBody(BodyModel):
    """SMPL-X with fixed shape, in TrioMan's z-up world.

    betas: [num_betas] shape coefficients; face_offset: [10475, 3] added to the template (ExAvatar);
    joint_offset: [55, 3] added to the regressed joints except the pelvis (ExAvatar). All in SMPL-X's frame.
    """

    name = "smplx"

    def __init__(self, model_dir: str | Path, gender: str = "neutral", num_betas: int = 10,
                 flat_hand_mean: bool = False, betas: np.ndarray | None = None,
                 face_offset: np.ndarray | None = None, joint_offset: np.ndarray | None = None,
                 dtype: torch.dtype = torch.float32):
        super().__init__()
        import smplx
        from smplx.lbs import blend_shapes, vertices2joints

        path = model_file(model_dir, gender)
        arrays = load_model_arrays(path)
        available = shape_coefficients(arrays)
        if not 1 <= num_betas <= available:
            raise ValueError(f"num_betas: {num_betas} requested, {path} has {available} shape coefficients")
        betas = np.zeros(num_betas) if betas is None else np.asarray(betas, dtype=np.float64)
        if betas.shape != (num_betas,) or not np.isfinite(betas).all():
            raise ValueError(f"betas: expected {num_betas} finite values (num_betas), got shape {list(betas.shape)}")
        for label, offset, shape in (("face_offset", face_offset, (NUM_VERTICES, 3)),
                                     ("joint_offset", joint_offset, (NUM_JOINTS, 3))):
            if offset is not None and (np.shape(offset) != shape or not np.isfinite(offset).all()):
                raise ValueError(f"{label}: expected {list(shape)} finite values, got shape {list(np.shape(offset))}")
        self.gender, self.num_betas, self.flat_hand_mean = gender, num_betas, flat_hand_mean
        self.joint_names = JOINT_NAMES
        with tempfile.TemporaryDirectory(prefix="trioman-smplx-") as tmp:
            plain = Path(tmp) / path.name
            np.savez(plain, **{k: v for k, v in arrays.items() if k in _KEYS})
            layer = smplx.SMPLX(tmp, gender=gender, num_betas=num_betas, use_pca=False, flat_hand_mean=flat_hand_mean,
                                num_expression_coeffs=10, use_face_contour=False, dtype=torch.float64)
        with torch.no_grad():
            template = layer.v_template + (0 if face_offset is None else torch.as_tensor(face_offset, dtype=torch.float64))
            v_shaped = template + blend_shapes(torch.as_tensor(betas)[None], layer.shapedirs)[0]
            joints = vertices2joints(layer.J_regressor, v_shaped[None])[0]
            if joint_offset is not None:
                offset = torch.as_tensor(joint_offset, dtype=torch.float64).clone()
                offset[0] = 0.0  # ExAvatar leaves the pelvis in place
                joints = joints + offset
        M = torch.as_tensor(Y_UP_TO_Z_UP)
        # posedirs [9 (J-1), V*3] -> per feature (joint, a, b) an offset field [V, 3]; in the z-up world the
        # feature is M (R - I) M^T, so the basis becomes P'_{cd} = M sum_ab M_ca M_db P_ab.
        P = layer.posedirs.reshape(NUM_JOINTS - 1, 3, 3, NUM_VERTICES, 3)
        P = torch.einsum("ca,db,jabvk,lk->jcdvl", M, M, P, M).reshape(-1, NUM_VERTICES, 3)
        weights = layer.lbs_weights
        K = int((weights > 0).sum(1).max())
        w, idx = torch.topk(weights, K, dim=1)
        parents = layer.parents.clone()
        parents[0] = -1
        self.register_buffer("parents", parents)
        self.register_buffer("rest_joints", (joints @ M.T).to(dtype))
        self.register_buffer("canonical_vertices", (v_shaped @ M.T).to(dtype))
        self.register_buffer("faces", layer.faces_tensor.clone())
        self.register_buffer("skin_indices", torch.where(w > 0, idx, torch.zeros_like(idx)))
        self.register_buffer("skin_weights", w.to(dtype))
        self.register_buffer("pose_correctives", P.to(dtype))
        mean = layer.pose_mean.reshape(-1, 3)[25:]  # smplx's order: root, 21 body, jaw, eyes, left, right hand
        self.register_buffer("hand_mean", mean.clone())  # [30, 3] SMPL-X frame, zeros with flat_hand_mean
        if "vt" in arrays:
            self.register_buffer("uvs", torch.as_tensor(arrays["vt"], dtype=dtype))
            self.register_buffer("uv_faces", torch.as_tensor(arrays["ft"].astype(np.int64)))
        else:
            self.uvs = self.uv_faces = None

    def forward(self, pose: torch.Tensor, trans: torch.Tensor) -> BodyOutput:
        """pose: [B, 55, 3] full axis-angle pose (z-up world), trans: [B, 3] -> BodyOutput."""
        self.check_pose(pose, trans)
        dtype = self.canonical_vertices.dtype
        pose, trans = pose.to(dtype), trans.to(dtype)
        A = skinning_transforms(self.parents.tolist(), self.rest_joints, pose, trans)
        R = axis_angle_to_matrix(pose[:, 1:])
        feature = (R - torch.eye(3, dtype=dtype)).reshape(len(pose), -1)
        rest = self.canonical_vertices + (feature @ self.pose_correctives.reshape(len(self.pose_correctives), -1)).reshape(
            len(pose), -1, 3)
        vertices = apply_transforms(blend_transforms(A, self.skin_indices, self.skin_weights), rest)
        G = A.clone()
        G[..., :3, 3] = A[..., :3, 3] + (A[..., :3, :3] @ self.rest_joints[..., None])[..., 0]
        return BodyOutput(vertices=vertices, joint_transforms=G, skinning_transforms=A)
