"""A trained Gaussian avatar posed in numpy (+ onnxruntime for the pose-dependent terms). No torch.

An ``Avatar`` comes from ``trioman.runtime.formats.load_avatar`` (the avatar format, docs/formats.md).
``Avatar.gaussians(pose, trans)`` computes exactly what the torch ``GaussianAvatar`` renders (its
"refined" set): pose-dependent deltas from the ONNX graph (carried from the graph's points to the
Gaussians when the avatar has ``pose_points``) added to the baked attributes, activated, then linear
blend skinning with the one sparse LBS of the runtime (``runtime.skeleton.blend_transforms``), blended
once per distinct skinning row.
"""

from __future__ import annotations

import os
from typing import Any, Mapping

import numpy as np

from trioman.runtime.gaussians import Gaussians
from trioman.runtime.rotations import matrix_to_quat, quat_to_matrix
from trioman.runtime.skeleton import Skeleton, apply_transforms, blend_transforms

SCALE_CLAMP = (-12.0, 2.0)  # log-scale clamp applied before exp (as GaussianAvatar does)


def _sigmoid(x: np.ndarray) -> np.ndarray:
    return 0.5 * (1.0 + np.tanh(0.5 * x))  # overflow-free logistic


def _distinct_rows(indices: np.ndarray, weights: np.ndarray) -> tuple[tuple[np.ndarray, np.ndarray], np.ndarray]:
    """The distinct rows of a sparse map (subdivided Gaussians share their source vertex's skinning).
    indices, weights: [N, K] -> (indices [U, K], weights [U, K]), row_of [N] with row n = distinct row row_of[n]."""
    rows = np.concatenate([indices.astype(np.float64), weights.astype(np.float64)], axis=1)
    _, first, row_of = np.unique(rows, axis=0, return_index=True, return_inverse=True)
    return (indices[first], weights[first]), row_of.reshape(-1)


def _carry(deltas: np.ndarray, indices: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """deltas [M, C] (float32) -> [N, C]: row n = sum_p weights[n, p] deltas[indices[n, p]], in the order of p."""
    out = weights[:, 0, None] * np.take(deltas, indices[:, 0], axis=0)  # take: a fast row gather
    for p in range(1, indices.shape[1]):
        out += weights[:, p, None] * np.take(deltas, indices[:, p], axis=0)
    return out


class Avatar:
    """A posable avatar. Build it with ``load_avatar``; the arrays are validated there.

    arrays: the gaussians.npz arrays (``positions`` [N,3], ``log_scales`` [N,S], ``rgb_logits`` [N,3],
    ``opacities`` [N], ``local_quats`` [N,4] when anisotropic, ``skin_indices``/``skin_weights`` [N,K],
    ``pose_indices``/``pose_weights`` [N,P] with ``meta["pose_points"]``).
    session: an onnxruntime InferenceSession of pose_dependent.onnx, or None.
    """

    def __init__(self, skeleton: Skeleton, arrays: Mapping[str, np.ndarray], meta: Mapping[str, Any],
                 session: Any = None, root: str | os.PathLike | None = None):
        self.skeleton = skeleton
        self.meta = dict(meta)
        self.root = root
        self._a = {k: np.asarray(v) for k, v in arrays.items()}
        for v in self._a.values():
            v.setflags(write=False)
        self._session = session
        self._skin_rows, self._skin_of = _distinct_rows(self._a["skin_indices"], self._a["skin_weights"])

    # ----------------------------------------------------------------------------------------------

    @property
    def num_gaussians(self) -> int:
        return int(self._a["positions"].shape[0])

    @property
    def anisotropic(self) -> bool:
        return "local_quats" in self._a

    @property
    def pose_dependent(self) -> bool:
        """True when the file carries the pose-dependent ONNX terms."""
        return self._session is not None

    @property
    def pose_joints(self) -> tuple[str, ...]:
        """The joints whose rotations condition the pose-dependent terms."""
        return tuple(self.meta.get("pose_joints", ()))

    @property
    def arrays(self) -> Mapping[str, np.ndarray]:
        """The baked, read-only gaussians.npz arrays."""
        return dict(self._a)

    def pose_deltas(self, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Pose-dependent deltas from the ONNX graph, at the Gaussians. pose: [J, 3] -> d_offset [N,3],
        d_log_scale [N,S], d_rgb [N,3] (float32)."""
        if self._session is None:
            raise ValueError("pose_dependent: this avatar has no pose-dependent terms (exported without them)")
        feed = {"pose": np.ascontiguousarray(pose, dtype=np.float32)}
        deltas = self._session.run(["d_offset", "d_log_scale", "d_rgb"], feed)
        if "pose_indices" not in self._a:
            return tuple(deltas)
        widths = np.cumsum([d.shape[1] for d in deltas])[:-1]
        carried = _carry(np.concatenate(deltas, axis=1), self._a["pose_indices"], self._a["pose_weights"])
        return tuple(np.split(carried, widths, axis=1))

    def gaussians(self, pose: np.ndarray, trans: np.ndarray, pose_dependent: bool = True) -> Gaussians:
        """World-space Gaussians at a pose. pose: [J, 3] axis-angle, trans: [3] -> Gaussians (float32).

        pose_dependent: add the pose-dependent deltas (when the avatar has them; ignored otherwise).
        """
        pose, trans = self.skeleton.check_pose(pose, trans)
        if pose.ndim != 2:
            raise ValueError(f"pose: expected shape [{self.skeleton.num_joints}, 3], got {list(pose.shape)}")
        a = self._a
        pos, log_s, logit = a["positions"], a["log_scales"], a["rgb_logits"]
        if pose_dependent and self._session is not None:
            # float32 sums, in the order GaussianAvatar.forward adds them.
            d_offset, d_log_scale, d_rgb = self.pose_deltas(pose.astype(np.float32))
            pos, log_s, logit = pos + d_offset, log_s + d_log_scale, logit + d_rgb
        A = self.skeleton.skinning_transforms(pose, trans)  # [J, 4, 4] float64
        T = np.take(blend_transforms(A, *self._skin_rows), self._skin_of, axis=0)  # [N, 3, 4]: each distinct row blended once
        means = apply_transforms(T, pos.astype(np.float64))
        N = self.num_gaussians
        if self.anisotropic:
            quats = matrix_to_quat(T[:, :, :3] @ quat_to_matrix(a["local_quats"]))
        else:
            quats = np.zeros((N, 4))
            quats[:, 0] = 1.0
        scales = np.exp(np.clip(log_s.astype(np.float64), *SCALE_CLAMP))
        scales = np.broadcast_to(scales, (N, 3))
        colors = _sigmoid(logit.astype(np.float64))
        f32 = np.float32
        return Gaussians(means.astype(f32), quats.astype(f32), np.ascontiguousarray(scales, dtype=f32),
                         a["opacities"].astype(f32), colors.astype(f32))

    def posed_ply(self, pose: np.ndarray, trans: np.ndarray, path: str | os.PathLike, pose_dependent: bool = True) -> None:
        """Write the Gaussians at a pose as a standard 3DGS .ply (trioman.runtime.ply.write_ply)."""
        from trioman.runtime.ply import write_ply  # ply needs runtime.formats, whose package loads this module

        write_ply(path, *self.gaussians(pose, trans, pose_dependent))

    def __repr__(self) -> str:
        return (f"Avatar({self.num_gaussians} Gaussians, {self.skeleton.num_joints} joints, "
                f"{'anisotropic' if self.anisotropic else 'isotropic'}, "
                f"pose_dependent={self.pose_dependent}, root={str(self.root)!r})")
