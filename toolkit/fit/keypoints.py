"""Where MediaPipe's 33 pose landmarks lie on the Anny body: a joint (the anatomical centres) or a surface
vertex (nose, ears, heels, toe tips), chosen once on the rest mesh by geometry (Anny's topology is fixed, so the
vertex indices hold for every phenotype).

Landmark order and names: ``trioman.runtime.person.landmarks.KEYPOINT_NAMES`` (MediaPipe's; "left" is the
person's left, Anny's ".L", at +x of a body facing -y).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from trioman.runtime.skeleton import SkinnedMesh

# landmark index -> Anny joint name
JOINT_LANDMARKS = {
    2: "eye.L", 5: "eye.R",
    11: "upperarm01.L", 12: "upperarm01.R", 13: "lowerarm01.L", 14: "lowerarm01.R", 15: "wrist.L", 16: "wrist.R",
    17: "finger5-1.L", 18: "finger5-1.R", 19: "finger2-1.L", 20: "finger2-1.R", 21: "finger1-2.L", 22: "finger1-2.R",
    23: "upperleg01.L", 24: "upperleg01.R", 25: "lowerleg01.L", 26: "lowerleg01.R", 27: "foot.L", 28: "foot.R",
}
VERTEX_LANDMARKS = (0, 7, 8, 29, 30, 31, 32)  # nose, ears, heels, toe tips
# landmark index -> offset (m, Anny's rest frame: +x the person's left, -y front, +z up) from its joint to where
# MediaPipe puts it, moved with the joint: the two skeletons' definitions differ (MediaPipe's shoulder lies ~36 mm
# above Anny's upperarm01, its ankle ~27 mm above Anny's foot joint). Fitted by `trioman bench landmarks --seed 2000
# --subjects 6 --size 540 --frames 60` (docs/bench/landmarks.md); the knees are left at the joint (their offset did
# not hold on the subjects it was not fitted on).
JOINT_OFFSETS: dict[int, tuple[float, float, float]] = {
    2: (-0.0086, 0.0032, 0.0078), 5: (0.0113, 0.0015, 0.0086), 11: (-0.0013, -0.0002, 0.0372), 12: (-0.0024, -0.0068, 0.0352),
    13: (-0.0190, -0.0223, 0.0178), 14: (0.0175, -0.0172, 0.0190), 15: (-0.0010, -0.0227, -0.0066), 16: (-0.0008, -0.0181, -0.0064),
    17: (-0.0149, -0.0228, 0.0086), 18: (0.0172, -0.0180, 0.0087), 19: (0.0034, 0.0149, -0.0126), 20: (-0.0042, 0.0169, -0.0123),
    21: (0.0329, -0.0014, -0.0198), 22: (-0.0357, 0.0010, -0.0193), 23: (-0.0098, -0.0176, -0.0094), 24: (0.0134, -0.0184, -0.0089),
    27: (-0.0038, -0.0090, 0.0278), 28: (0.0016, -0.0020, 0.0256),
}
# how much each landmark counts in the reprojection term (hands and face points are less reliable than limbs)
LANDMARK_WEIGHT = {**{i: 1.0 for i in range(33)}, **{i: 0.3 for i in (0, 2, 5, 7, 8, 17, 18, 19, 20, 21, 22)}}
# limbs whose 3D direction the fit takes from the world landmarks: (from, to) landmark indices. The legs and the
# torso only: the arms' directions are too far off to help (docs/fit.md: median 17-27 degrees against 5-9).
LIMBS = ((23, 25), (25, 27), (24, 26), (26, 28), (11, 12), (23, 24), (11, 23), (12, 24))


@dataclass(frozen=True)
class Correspondence:
    """Landmarks on a body: ``landmarks`` [M] MediaPipe indices, each a joint (``joint`` >= 0) or a vertex."""

    landmarks: np.ndarray  # [M] int
    joint: np.ndarray  # [M] int, -1 where the landmark is a vertex
    vertex: np.ndarray  # [M] int, -1 where it is a joint
    weight: np.ndarray  # [M] float
    offset: np.ndarray  # [M, 3] float, a joint landmark's rest-frame offset from its joint (0 for vertices)

    def points(self, mesh: SkinnedMesh, pose: np.ndarray, trans: np.ndarray) -> np.ndarray:
        """The landmarks on ``mesh`` posed (the reference: full forward kinematics and skinning). -> [M, 3] world"""
        G = mesh.skeleton.forward_kinematics(pose, trans)
        A = G @ np.linalg.inv(mesh.skeleton.forward_kinematics(np.zeros_like(pose), np.zeros(3)))  # skinning transforms
        j = self.joint.clip(0)
        at_joint = G[j, :3, 3] + np.einsum("mij,mj->mi", A[j, :3, :3], self.offset)
        return np.where((self.joint >= 0)[:, None], at_joint, mesh.pose(pose, trans)[self.vertex.clip(0)])


def _dominant(mesh: SkinnedMesh) -> np.ndarray:
    return np.asarray(mesh.skeleton.joint_names)[np.argmax(mesh.dense_weights(), axis=1)].astype(str)


def correspondence(mesh: SkinnedMesh) -> Correspondence:
    """The 27 landmarks MediaPipe gives that have a place on ``mesh`` (Anny's topology; mouth corners are left out)."""
    sk = mesh.skeleton
    v = mesh.vertices
    dom = _dominant(mesh)
    head = dom == "head"
    eye_z = 0.5 * (sk.joints[sk.index("eye.L"), 2] + sk.joints[sk.index("eye.R"), 2])
    picks: dict[int, int] = {}
    face = head & (np.abs(v[:, 0]) < 0.012) & (v[:, 2] < eye_z) & (v[:, 2] > eye_z - 0.06)
    picks[0] = int(np.flatnonzero(face)[np.argmin(v[face, 1])])  # nose tip: the front-most point below the eyes
    level = head & (np.abs(v[:, 2] - eye_z) < 0.03)
    picks[7] = int(np.flatnonzero(level)[np.argmax(v[level, 0])])  # left ear: the widest point at eye height
    picks[8] = int(np.flatnonzero(level)[np.argmin(v[level, 0])])
    for side, heel, toe in ((".L", 29, 31), (".R", 30, 32)):
        ankle_z = sk.joints[sk.index("foot" + side), 2]
        foot = np.char.startswith(dom, ("foot" + side)) | (np.char.startswith(dom, "toe") & np.char.endswith(dom, side))
        low = foot & (v[:, 2] < ankle_z)
        picks[heel] = int(np.flatnonzero(low)[np.argmax(v[low, 1])])  # the back-most point below the ankle
        picks[toe] = int(np.flatnonzero(foot)[np.argmin(v[foot, 1])])  # the front-most point of the foot
    marks = sorted(set(JOINT_LANDMARKS) | set(VERTEX_LANDMARKS))
    return Correspondence(
        landmarks=np.array(marks),
        joint=np.array([sk.index(JOINT_LANDMARKS[m]) if m in JOINT_LANDMARKS else -1 for m in marks]),
        vertex=np.array([picks.get(m, -1) for m in marks]),
        weight=np.array([LANDMARK_WEIGHT[m] for m in marks]),
        offset=np.array([JOINT_OFFSETS.get(m, (0.0, 0.0, 0.0)) if m in JOINT_LANDMARKS else (0.0, 0.0, 0.0) for m in marks]),
    )
