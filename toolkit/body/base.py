"""The body-model interface the rest of the toolkit uses.

A body model is a skinned mesh with a kinematic tree. Poses are axis-angle per joint [B, J, 3] in
world-aligned axes plus a root translation [B, 3] (see trioman.runtime.skeleton for the exact FK
and LBS convention, which every implementation follows so that runtime/ can pose the exported
arrays in numpy).
"""

from __future__ import annotations

import abc
from typing import NamedTuple

import numpy as np
import torch

from trioman.runtime.skeleton import Skeleton, SkinnedMesh


class BodyOutput(NamedTuple):
    vertices: torch.Tensor  # [B, V, 3] posed vertices (m)
    joint_transforms: torch.Tensor  # [B, J, 4, 4] world transforms G of each joint
    skinning_transforms: torch.Tensor  # [B, J, 4, 4] A = G [I | -j_rest], maps rest points


class BodyModel(torch.nn.Module, abc.ABC):
    """Skinned body with fixed shape. Buffers hold the canonical (rest) mesh and skeleton."""

    name: str
    joint_names: tuple[str, ...]
    parents: torch.Tensor  # [J] long, parents[0] == -1
    rest_joints: torch.Tensor  # [J, 3]
    canonical_vertices: torch.Tensor  # [V, 3] rest vertices = vertices at zero pose
    faces: torch.Tensor  # [F, 3] long
    skin_indices: torch.Tensor  # [V, K] long
    skin_weights: torch.Tensor  # [V, K]
    uvs: torch.Tensor | None  # [T, 2]
    uv_faces: torch.Tensor | None  # [F, 3]
    pose_correctives: torch.Tensor  # optional (SMPL-X): [9 (J-1), V, 3] pose blend shapes, see runtime.skeleton

    @property
    def num_joints(self) -> int:
        return len(self.joint_names)

    @abc.abstractmethod
    def forward(self, pose: torch.Tensor, trans: torch.Tensor) -> BodyOutput:
        """pose: [B, J, 3] axis-angle, trans: [B, 3] -> BodyOutput."""

    def check_pose(self, pose: torch.Tensor, trans: torch.Tensor) -> None:
        J = self.num_joints
        if pose.ndim != 3 or pose.shape[1:] != (J, 3):
            raise ValueError(f"pose: expected shape [B, {J}, 3], got {list(pose.shape)}")
        if trans.shape != (pose.shape[0], 3):
            raise ValueError(f"trans: expected shape [{pose.shape[0]}, 3], got {list(trans.shape)}")
        for name, t in (("pose", pose), ("trans", trans)):
            bad = ~torch.isfinite(t)
            if bad.any():
                raise ValueError(f"{name}: {int(bad.sum())} non-finite value(s) (NaN/Inf)")

    def to_skinned_mesh(self) -> SkinnedMesh:
        """The model as plain numpy arrays, posable by trioman.runtime.skeleton without torch."""

        def np64(t: torch.Tensor) -> np.ndarray:
            return t.detach().cpu().double().numpy()

        skeleton = Skeleton(self.joint_names, self.parents.cpu().numpy().astype(np.int32), np64(self.rest_joints))
        w = self.skin_weights.detach().cpu().double()
        w = (w / w.sum(dim=1, keepdim=True)).float().numpy()
        correctives = getattr(self, "pose_correctives", None)
        return SkinnedMesh(
            skeleton=skeleton,
            vertices=np64(self.canonical_vertices),
            faces=self.faces.cpu().numpy().astype(np.int32),
            skin_indices=self.skin_indices.cpu().numpy().astype(np.int32),
            skin_weights=w,
            uvs=None if self.uvs is None else self.uvs.detach().cpu().float().numpy(),
            uv_faces=None if self.uv_faces is None else self.uv_faces.cpu().numpy().astype(np.int32),
            pose_correctives=None if correctives is None else correctives.detach().cpu().float().numpy(),
        )
