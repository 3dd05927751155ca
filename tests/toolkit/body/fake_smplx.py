"""A structurally valid SMPL-X model file with random values, for tests (the real one is licensed).

Real keys, dtypes and sizes of ``SMPLX_{GENDER}.npz`` (v1.1): 10,475 vertices, 20,908 faces, 55 joints
with SMPL-X's kinematic tree, 400 shape + expression directions, 486 pose directions, hand PCA and hand
means, landmark faces. smplx selects fixed vertex ids (< 10,475) and landmark faces, so the sizes must
be exact. The values are a stick figure: each joint owns a cluster of vertices around its rest
position (y up, facing +z, metres), skinned mostly to it; the joint regressor averages the cluster.
Like the real files it also holds Python-object arrays (``joint2num``, ``part2num``), which a reader
must skip rather than unpickle.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

NUM_VERTICES = 10475
NUM_FACES = 20908
NUM_JOINTS = 55
PARENTS = np.array([-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 15, 15, 15,
                    20, 25, 26, 20, 28, 29, 20, 31, 32, 20, 34, 35, 20, 37, 38,
                    21, 40, 41, 21, 43, 44, 21, 46, 47, 21, 49, 50, 21, 52, 53])
_BODY = {  # left side (+x); the right side mirrors x
    0: (0.0, 0.0, 0.0), 1: (0.06, -0.09, 0.0), 3: (0.0, 0.11, 0.0), 4: (0.1, -0.47, 0.0), 6: (0.0, 0.24, 0.0),
    7: (0.1, -0.87, -0.03), 9: (0.0, 0.30, 0.0), 10: (0.11, -0.93, 0.1), 12: (0.0, 0.5, 0.0), 13: (0.07, 0.42, 0.0),
    15: (0.0, 0.6, 0.02), 16: (0.17, 0.44, 0.0), 18: (0.43, 0.43, 0.0), 20: (0.68, 0.43, 0.0),
    22: (0.0, 0.57, 0.06), 23: (0.03, 0.66, 0.08),
}
_MIRROR = {2: 1, 5: 4, 8: 7, 11: 10, 14: 13, 17: 16, 19: 18, 21: 20, 24: 23}


def rest_joints() -> np.ndarray:
    """[55, 3] the stick figure's rest joints (SMPL-X frame: y up, facing +z)."""
    J = np.zeros((NUM_JOINTS, 3))
    for j, p in _BODY.items():
        J[j] = p
    for j, src in _MIRROR.items():
        J[j] = J[src] * (-1, 1, 1)
    for side, (first, wrist) in enumerate(((25, 20), (40, 21))):
        sign = 1 - 2 * side
        for finger in range(5):  # index, middle, pinky, ring, thumb: 3 joints each
            for k in range(3):
                J[first + 3 * finger + k] = J[wrist] + (sign * (0.08 + 0.025 * k), -0.005 * k, 0.03 - 0.015 * finger)
    return J


def write_fake_smplx(path: str | Path, seed: int = 0) -> Path:
    """Write a fake ``SMPLX_*.npz`` at ``path`` (its parent folder is created) and return the path."""
    rng = np.random.default_rng(seed)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    J = rest_joints()
    owner = np.arange(NUM_VERTICES) % NUM_JOINTS  # the joint owning each vertex
    small = (owner >= 22)  # face and hand joints: small clusters
    radius = np.where(small, 0.008, 0.04)[:, None]
    offsets = rng.normal(size=(NUM_VERTICES, 3)) * radius
    for j in range(NUM_JOINTS):  # zero-mean clusters: the regressor averages back to the joint
        offsets[owner == j] -= offsets[owner == j].mean(0)
    v_template = J[owner] + offsets
    # Skinning: own joint (0.6-1), its parent and one random joint share the rest; 3 influences, rows sum to 1.
    weights = np.zeros((NUM_VERTICES, NUM_JOINTS))
    own = rng.uniform(0.6, 1.0, NUM_VERTICES)
    split = rng.uniform(0, 1, NUM_VERTICES)
    parent = np.where(PARENTS[owner] < 0, 0, PARENTS[owner])
    other = rng.integers(0, NUM_JOINTS, NUM_VERTICES)
    rows = np.arange(NUM_VERTICES)
    weights[rows, owner] += own
    weights[rows, parent] += (1 - own) * split
    weights[rows, other] += (1 - own) * (1 - split)
    J_regressor = np.zeros((NUM_JOINTS, NUM_VERTICES))
    for j in range(NUM_JOINTS):
        members = np.flatnonzero(owner == j)
        J_regressor[j, members] = 1.0 / len(members)
    # Faces: triangles inside one cluster.
    face_owner = rng.integers(0, NUM_JOINTS, NUM_FACES)
    faces = np.empty((NUM_FACES, 3), dtype=np.int64)
    for j in range(NUM_JOINTS):
        members = np.flatnonzero(owner == j)
        sel = np.flatnonzero(face_owner == j)
        faces[sel] = np.stack([rng.choice(members, 3, replace=False) for _ in sel]) if len(sel) else faces[sel]
    num_vt = 11313
    bary = rng.uniform(0.1, 1.0, (51, 3))
    dyn_bary = rng.uniform(0.1, 1.0, (79, 17, 3))
    kintree = np.stack([np.where(PARENTS < 0, 2**32 - 1, PARENTS), np.arange(NUM_JOINTS)]).astype(np.int64)
    q_l, _ = np.linalg.qr(rng.normal(size=(45, 45)))
    q_r, _ = np.linalg.qr(rng.normal(size=(45, 45)))
    arrays = {
        "v_template": v_template.astype(np.float64),
        "f": faces.astype(np.uint32),
        "J_regressor": J_regressor,
        "weights": weights,
        "kintree_table": kintree,
        "shapedirs": (rng.normal(size=(NUM_VERTICES, 3, 400)) * 0.002).astype(np.float32),
        "posedirs": (rng.normal(size=(NUM_VERTICES, 3, 486)) * 0.002).astype(np.float32),
        "hands_meanl": rng.normal(scale=0.15, size=45),
        "hands_meanr": rng.normal(scale=0.15, size=45),
        "hands_componentsl": q_l,
        "hands_componentsr": q_r,
        "hands_coeffsl": rng.normal(size=(1554, 45)) * 0.1,
        "hands_coeffsr": rng.normal(size=(1554, 45)) * 0.1,
        "lmk_faces_idx": rng.integers(0, NUM_FACES, 51).astype(np.int64),
        "lmk_bary_coords": bary / bary.sum(1, keepdims=True),
        "dynamic_lmk_faces_idx": rng.integers(0, NUM_FACES, (79, 17)).astype(np.int64),
        "dynamic_lmk_bary_coords": dyn_bary / dyn_bary.sum(2, keepdims=True),
        "vt": rng.uniform(0, 1, (num_vt, 2)),
        "ft": rng.integers(0, num_vt, (NUM_FACES, 3)).astype(np.uint32),
        "joint2num": np.array({"pelvis": 0}, dtype=object),
        "part2num": np.array({"global": 0}, dtype=object),
    }
    with open(path, "wb") as f:
        np.savez(f, **arrays)
    return path
