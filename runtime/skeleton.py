"""Skeleton forward kinematics and linear blend skinning in numpy (``Skeleton``, ``SkinnedMesh``).

The convention (FK, LBS, pose-corrective blend shapes): docs/formats.md, "Forward kinematics and skinning"
and "``body.npz``".
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import numpy as np

from trioman.runtime.rotations import axis_angle_to_matrix


def _finite(name: str, a: np.ndarray) -> None:
    bad = ~np.isfinite(a)
    if bad.any():
        raise ValueError(f"{name}: {int(bad.sum())} non-finite value(s) (NaN/Inf)")


def _shape(name: str, a: np.ndarray, expected: tuple) -> None:
    """expected: a tuple of ints or None (any)."""
    if a.ndim != len(expected) or any(e is not None and s != e for s, e in zip(a.shape, expected)):
        want = "[" + ", ".join("*" if e is None else str(e) for e in expected) + "]"
        raise ValueError(f"{name}: expected shape {want}, got {list(a.shape)}")


def blend_transforms(A: np.ndarray, skin_indices: np.ndarray, skin_weights: np.ndarray) -> np.ndarray:
    """Sparse linear blend of skinning transforms: the one LBS of the runtime.

    A: [..., J, 4, 4] (skinning transforms), skin_indices / skin_weights: [N, K] -> [..., N, 3, 4]
    float64, ``sum_k skin_weights[n, k] * A[skin_indices[n, k], :3, :]``. Memory stays ~N * 12 floats
    per leading index (the K influences are accumulated one at a time).
    """
    A = np.asarray(A, dtype=np.float64)
    idx = np.asarray(skin_indices)
    w = np.asarray(skin_weights, dtype=np.float64)
    out = np.zeros(A.shape[:-3] + (idx.shape[0], 3, 4))
    for k in range(idx.shape[1]):
        out += w[:, k, None, None] * A[..., idx[:, k], :3, :]
    return out


def apply_transforms(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Per-point 3x4 transforms applied to points. T: [..., N, 3, 4], points: [N, 3] -> [..., N, 3]."""
    return np.einsum("...nab,nb->...na", T[..., :3], points) + T[..., 3]


@dataclass(frozen=True, eq=False)
class Skeleton:
    """A kinematic tree. Joints are ordered so that parents[j] < j and parents[0] == -1."""

    joint_names: tuple[str, ...]  # [J]
    parents: np.ndarray  # [J] int32
    joints: np.ndarray  # [J, 3] float64 rest joint positions (m)

    def __post_init__(self) -> None:
        parents = np.asarray(self.parents)
        joints = np.asarray(self.joints, dtype=np.float64)
        J = len(self.joint_names)
        if J == 0:
            raise ValueError("joint_names: the skeleton has no joints")
        if len(set(self.joint_names)) != J:
            raise ValueError("joint_names: names must be unique")
        _shape("parents", parents, (J,))
        if not np.issubdtype(parents.dtype, np.integer):
            raise ValueError(f"parents: expected integers, got dtype {parents.dtype}")
        if parents[0] != -1 or np.any(parents[1:] < 0) or np.any(parents[1:] >= np.arange(1, J)):
            raise ValueError("parents: expected parents[0] == -1 and 0 <= parents[j] < j for j > 0")
        _shape("joints", joints, (J, 3))
        _finite("joints", joints)
        object.__setattr__(self, "joint_names", tuple(str(n) for n in self.joint_names))
        object.__setattr__(self, "parents", parents.astype(np.int32))
        object.__setattr__(self, "joints", joints)

    @property
    def num_joints(self) -> int:
        return len(self.joint_names)

    def index(self, name: str) -> int:
        """The index of a joint by name (clear error for an unknown joint)."""
        try:
            return self.joint_names.index(name)
        except ValueError:
            raise ValueError(f"joint: unknown joint name {name!r} ({self.num_joints} joints)") from None

    def check_pose(self, pose: np.ndarray, trans: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        pose = np.asarray(pose, dtype=np.float64)
        trans = np.asarray(trans, dtype=np.float64)
        if pose.shape[-2:] != (self.num_joints, 3):
            raise ValueError(f"pose: expected shape [..., {self.num_joints}, 3], got {list(pose.shape)}")
        if trans.shape != pose.shape[:-2] + (3,):
            raise ValueError(f"trans: expected shape {list(pose.shape[:-2]) + [3]}, got {list(trans.shape)}")
        _finite("pose", pose)
        _finite("trans", trans)
        return pose, trans

    def forward_kinematics(self, pose: np.ndarray, trans: np.ndarray) -> np.ndarray:
        """World transforms G. pose: [..., J, 3] axis-angle, trans: [..., 3] -> [..., J, 4, 4] float64."""
        pose, trans = self.check_pose(pose, trans)
        R = axis_angle_to_matrix(pose)  # [..., J, 3, 3]
        local = np.zeros(pose.shape[:-1] + (4, 4))
        local[..., :3, :3] = R
        offsets = self.joints - np.where(self.parents[:, None] >= 0, self.joints[self.parents], 0.0)
        local[..., :3, 3] = offsets
        local[..., 0, :3, 3] = self.joints[0] + trans
        local[..., 3, 3] = 1.0
        G = np.empty_like(local)
        G[..., 0, :, :] = local[..., 0, :, :]
        for c in range(1, self.num_joints):
            G[..., c, :, :] = G[..., self.parents[c], :, :] @ local[..., c, :, :]
        return G

    def skinning_transforms(self, pose: np.ndarray, trans: np.ndarray) -> np.ndarray:
        """A_c = G_c [I | -j_c]: maps rest-space points. [..., J, 3], [..., 3] -> [..., J, 4, 4]."""
        G = self.forward_kinematics(pose, trans)
        A = G.copy()
        A[..., :3, 3] -= np.einsum("...jab,jb->...ja", G[..., :3, :3], self.joints)
        return A


@dataclass(frozen=True, eq=False)
class SkinnedMesh:
    """A canonical (rest) triangle mesh skinned to a skeleton with sparse LBS weights."""

    skeleton: Skeleton
    vertices: np.ndarray  # [V, 3] float64 rest vertices (m)
    faces: np.ndarray  # [F, 3] int32
    skin_indices: np.ndarray  # [V, K] int32 joint index per influence
    skin_weights: np.ndarray  # [V, K] float32, rows sum to 1
    uvs: np.ndarray | None = None  # [T, 2] float32 texture coordinates (v up)
    uv_faces: np.ndarray | None = None  # [F, 3] int32 rows of uvs per face corner
    pose_correctives: np.ndarray | None = None  # [9 (J-1), V, 3] float32 pose blend shapes (SMPL-X), docs/formats.md

    def __post_init__(self) -> None:
        V = len(self.vertices)
        vertices = np.asarray(self.vertices, dtype=np.float64)
        faces = np.asarray(self.faces)
        skin_indices = np.asarray(self.skin_indices)
        skin_weights = np.asarray(self.skin_weights, dtype=np.float32)
        _shape("vertices", vertices, (None, 3))
        _finite("vertices", vertices)
        if V == 0:
            raise ValueError("vertices: the mesh has no vertices")
        _shape("faces", faces, (None, 3))
        if not np.issubdtype(faces.dtype, np.integer):
            raise ValueError(f"faces: expected integers, got dtype {faces.dtype}")
        if faces.size and (faces.min() < 0 or faces.max() >= V):
            raise ValueError(f"faces: indices must lie in [0, {V}), got [{faces.min()}, {faces.max()}]")
        _shape("skin_indices", skin_indices, (V, None))
        _shape("skin_weights", skin_weights, skin_indices.shape)
        if not np.issubdtype(skin_indices.dtype, np.integer):
            raise ValueError(f"skin_indices: expected integers, got dtype {skin_indices.dtype}")
        J = self.skeleton.num_joints
        if skin_indices.size and (skin_indices.min() < 0 or skin_indices.max() >= J):
            raise ValueError(f"skin_indices: joint indices must lie in [0, {J}), got [{skin_indices.min()}, {skin_indices.max()}]")
        _finite("skin_weights", skin_weights)
        if np.any(skin_weights < 0):
            raise ValueError(f"skin_weights: {int((skin_weights < 0).sum())} negative weight(s)")
        sums = skin_weights.sum(axis=1, dtype=np.float64)
        if np.any(np.abs(sums - 1.0) > 1e-4):
            worst = int(np.argmax(np.abs(sums - 1.0)))
            raise ValueError(f"skin_weights: rows must sum to 1, vertex {worst} sums to {sums[worst]:.6f}")
        if (self.uvs is None) != (self.uv_faces is None):
            raise ValueError("uvs: uvs and uv_faces must be given together")
        if self.uvs is not None:
            uvs = np.asarray(self.uvs, dtype=np.float32)
            uv_faces = np.asarray(self.uv_faces)
            _shape("uvs", uvs, (None, 2))
            _finite("uvs", uvs)
            _shape("uv_faces", uv_faces, faces.shape)
            if uv_faces.size and (uv_faces.min() < 0 or uv_faces.max() >= len(uvs)):
                raise ValueError(f"uv_faces: indices must lie in [0, {len(uvs)}), got [{uv_faces.min()}, {uv_faces.max()}]")
            object.__setattr__(self, "uvs", uvs)
            object.__setattr__(self, "uv_faces", uv_faces.astype(np.int32))
        if self.pose_correctives is not None:
            P = np.asarray(self.pose_correctives, dtype=np.float32)
            _shape("pose_correctives", P, (9 * (J - 1), V, 3))
            _finite("pose_correctives", P)
            object.__setattr__(self, "pose_correctives", P)
        object.__setattr__(self, "vertices", vertices)
        object.__setattr__(self, "faces", faces.astype(np.int32))
        object.__setattr__(self, "skin_indices", skin_indices.astype(np.int32))
        object.__setattr__(self, "skin_weights", skin_weights)

    @property
    def num_vertices(self) -> int:
        return len(self.vertices)

    def dense_weights(self) -> np.ndarray:
        """[V, J] float64 skinning weights."""
        W = np.zeros((self.num_vertices, self.skeleton.num_joints))
        np.add.at(W, (np.arange(self.num_vertices)[:, None], self.skin_indices), self.skin_weights)
        return W

    def corrected_rest(self, pose: np.ndarray) -> np.ndarray:
        """Rest vertices moved by the pose-corrective blend shapes. pose: [B, J, 3] -> [B, V, 3] float64
        (the rest vertices broadcast to [1, V, 3] when the mesh has none)."""
        if self.pose_correctives is None:
            return self.vertices[None]
        R = axis_angle_to_matrix(np.asarray(pose, dtype=np.float64)[:, 1:])  # [B, J-1, 3, 3]
        feature = (R - np.eye(3)).reshape(len(R), -1).astype(np.float32)  # [B, 9 (J-1)]
        offsets = feature @ self.pose_correctives.reshape(len(self.pose_correctives), -1)  # float32 GEMM, ~1e-9 m
        return self.vertices[None] + offsets.astype(np.float64).reshape(len(R), self.num_vertices, 3)

    def pose(self, pose: np.ndarray, trans: np.ndarray, chunk: int = 16) -> np.ndarray:
        """Posed vertices by LBS (after the pose correctives, if any). pose: [..., J, 3], trans: [..., 3]
        -> [..., V, 3] float64.

        Batches are processed ``chunk`` poses at a time so memory stays ~chunk * V * 12 floats.
        """
        A = self.skeleton.skinning_transforms(pose, trans)  # [..., J, 4, 4]
        lead = A.shape[:-3]
        A = A.reshape((-1,) + A.shape[-3:])
        flat_pose = np.asarray(pose, dtype=np.float64).reshape((-1,) + self.skeleton.joints.shape)
        out = np.empty((len(A), self.num_vertices, 3))
        for s in range(0, len(A), chunk):
            T = blend_transforms(A[s : s + chunk], self.skin_indices, self.skin_weights)  # [b, V, 3, 4]
            rest = self.corrected_rest(flat_pose[s : s + chunk])  # [b or 1, V, 3]
            out[s : s + chunk] = np.einsum("...nab,...nb->...na", T[..., :3], rest) + T[..., 3]
        return out.reshape(lead + (self.num_vertices, 3))

    def to_arrays(self) -> dict[str, np.ndarray]:
        """Plain arrays (no objects) for np.savez; inverse of from_arrays."""
        arrays = {
            "joint_names": np.array(self.skeleton.joint_names, dtype=np.str_),
            "parents": self.skeleton.parents,
            "joints": self.skeleton.joints,
            "vertices": self.vertices,
            "faces": self.faces,
            "skin_indices": self.skin_indices,
            "skin_weights": self.skin_weights,
        }
        if self.uvs is not None:
            arrays["uvs"] = self.uvs
            arrays["uv_faces"] = self.uv_faces
        if self.pose_correctives is not None:
            arrays["pose_correctives"] = self.pose_correctives
        return arrays

    @classmethod
    def from_arrays(cls, arrays: Mapping[str, np.ndarray]) -> "SkinnedMesh":
        """Build and validate from to_arrays() output; ValueError messages start with the field name."""
        required = ("joint_names", "parents", "joints", "vertices", "faces", "skin_indices", "skin_weights")
        for key in required:
            if key not in arrays:
                raise ValueError(f"{key}: missing array")
        names = np.asarray(arrays["joint_names"])
        if names.ndim != 1 or names.dtype.kind != "U":
            raise ValueError(f"joint_names: expected a 1-D unicode array, got dtype {names.dtype} shape {list(names.shape)}")
        skeleton = Skeleton(tuple(names.tolist()), np.asarray(arrays["parents"]), np.asarray(arrays["joints"]))
        return cls(
            skeleton=skeleton,
            vertices=np.asarray(arrays["vertices"]),
            faces=np.asarray(arrays["faces"]),
            skin_indices=np.asarray(arrays["skin_indices"]),
            skin_weights=np.asarray(arrays["skin_weights"]),
            uvs=np.asarray(arrays["uvs"]) if "uvs" in arrays else None,
            uv_faces=np.asarray(arrays["uv_faces"]) if "uv_faces" in arrays else None,
            pose_correctives=np.asarray(arrays["pose_correctives"]) if "pose_correctives" in arrays else None,
        )
