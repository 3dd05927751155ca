"""The open Anny body model (PyPI ``anny``, NAVER, Apache-2.0 code, CC0 MakeHuman assets).

Anny's mesh: 13,718 vertices, 27,420 triangles with UVs, 104 bones (body, fingers, toes, eyes),
z-up, metres, the subject facing -y. Shape comes from six phenotype values in [0, 1] (gender, age,
muscle, weight, height, proportions). Anny builds a cache (~790 MB, ~2 min) on first use.

We drive Anny's own forward pass ("local-ref" deltas with the reference orientations switched off),
which makes it SMPL-like: the zero pose is the rest mesh and a joint rotation is an axis-angle in
world-aligned axes about the joint's rest position; exactly the convention of
trioman.runtime.skeleton, so the numpy FK + LBS reproduces this model.
"""

from __future__ import annotations

import torch

from trioman.toolkit.body.base import BodyModel, BodyOutput
from trioman.toolkit.rotations import axis_angle_to_matrix

PHENOTYPE_LABELS = ("gender", "age", "muscle", "weight", "height", "proportions")


class AnnyBody(BodyModel):
    """Anny with a fixed phenotype. ``phenotype`` maps PHENOTYPE_LABELS to values in [0, 1]."""

    name = "anny"

    def __init__(self, phenotype: dict[str, float] | None = None, dtype: torch.dtype = torch.float32):
        super().__init__()
        phenotype = dict(phenotype or {})
        unknown = sorted(set(phenotype) - set(PHENOTYPE_LABELS))
        if unknown:
            raise ValueError(f"phenotype: unknown key(s) {unknown}; expected a subset of {list(PHENOTYPE_LABELS)}")
        for key, value in phenotype.items():
            if not (0.0 <= float(value) <= 1.0):
                raise ValueError(f"phenotype: {key} must lie in [0, 1], got {value}")
        self.phenotype = {k: float(phenotype.get(k, 0.5)) for k in PHENOTYPE_LABELS}

        import anny

        # Pure-torch dense LBS: deterministic, and no warp kernel compilation or banner.
        model = anny.Anny(skinning_method="lbs").to(dtype)
        # No reference orientations: identity deltas give the rest pose (SMPL-like, see module doc).
        model.reference_bone_orientations = None
        self._anny = model
        self.joint_names = tuple(model.bone_labels)
        with torch.no_grad():
            pheno = torch.tensor([[self.phenotype[k] for k in model.phenotype_labels]], dtype=dtype)
            self._pheno = pheno
            rest = model(None, phenotype_kwargs=pheno)
        self.register_buffer("parents", torch.as_tensor(model.bone_parents, dtype=torch.long))
        self.register_buffer("rest_joints", rest["rest_bone_heads"][0].clone())
        self.register_buffer("canonical_vertices", rest["rest_vertices"][0].clone())
        self.register_buffer("faces", model.faces.long().clone())
        self.register_buffer("skin_indices", model.vertex_bone_indices.long().clone())
        self.register_buffer("skin_weights", model.vertex_bone_weights.to(dtype).clone())
        self.register_buffer("uvs", model.texture_coordinates.to(dtype).clone())
        self.register_buffer("uv_faces", model.face_texture_coordinate_indices.long().clone())
        self.register_buffer("_rest_rot", rest["rest_bone_poses"][0, :, :3, :3].clone())

    def forward(self, pose: torch.Tensor, trans: torch.Tensor) -> BodyOutput:
        self.check_pose(pose, trans)
        B, J = pose.shape[:2]
        dtype = self.canonical_vertices.dtype
        pose, trans = pose.to(dtype), trans.to(dtype)
        delta = torch.zeros(B, J, 4, 4, dtype=dtype, device=pose.device)
        delta[..., :3, :3] = axis_angle_to_matrix(pose)
        delta[..., 3, 3] = 1.0
        # The root delta is its world pose: rotate about the rest root joint, then translate.
        delta[:, 0, :3, 3] = self.rest_joints[0] + trans
        out = self._anny(delta, phenotype_kwargs=self._pheno.expand(B, -1), pose_parameterization="local-ref")
        # Anny's bone poses carry each bone's rest orientation: G = W [R_rest^T | 0].
        W = out["bone_poses"]
        G = W.clone()
        G[..., :3, :3] = W[..., :3, :3] @ self._rest_rot.transpose(-1, -2)
        A = G.clone()
        A[..., :3, 3] = G[..., :3, 3] - (G[..., :3, :3] @ self.rest_joints[..., None])[..., 0]
        return BodyOutput(vertices=out["vertices"], joint_transforms=G, skinning_transforms=A)
