"""The inputs of the augment tests (tests/runtime/test_augment.py, tests/runtime/test_shards.py), built without torch:
a figure of boxes on the 18-joint skeleton of tests/runtime/factories.py (each box skinned to one joint, a colour
field painted on it), a 6-frame 32x32 subject of it (2 train + 4 test frames, the painted mesh as the images), an
avatar of Gaussians on its vertices, the shipped Refiner and Examiner (trioman.runtime.pretrained) and small Refiner
ONNX files that onnx builds (tests.runtime.factories.block_refiner)."""

from __future__ import annotations

import shutil
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import trimesh

from tests.runtime.factories import JOINTS, NAMES, PARENTS, block_refiner, write
from trioman.runtime.cameras import intrinsics, look_at
from trioman.runtime.formats import save_avatar, save_subject
from trioman.runtime.mesh_raster import interpolate, rasterize_mesh
from trioman.runtime.pretrained import shipped_path
from trioman.runtime.skeleton import Skeleton, SkinnedMesh

SIZE = 32  # the subject's images are SIZE x SIZE
FRAMES, TRAIN = 6, 2  # frames of the subject, the first TRAIN of them "train", the rest "test"
LIFT = np.array([0.0, 0.0, 0.9])  # the skeleton's feet at z ~ 0.05
BACKGROUND = (1.0, 1.0, 1.0)
STEP = 3  # the avatar's training step as its avatar.json records it

# (joint the box is skinned to, from, to, width x depth) in the skeleton's frame (before LIFT)
_BOXES = [
    ("spine01", (0, 0, -0.05), (0, 0, 0.55), (0.32, 0.18)),
    ("head", (0, 0, 0.58), (0, 0, 0.82), (0.16, 0.18)),
    ("upperleg01.L", (0.1, 0, -0.05), (0.12, 0, -0.45), (0.12, 0.12)),
    ("lowerleg01.L", (0.12, 0, -0.45), (0.14, 0, -0.85), (0.1, 0.1)),
    ("upperleg01.R", (-0.1, 0, -0.05), (-0.12, 0, -0.45), (0.12, 0.12)),
    ("lowerleg01.R", (-0.12, 0, -0.45), (-0.14, 0, -0.85), (0.1, 0.1)),
    ("upperarm01.L", (0.18, 0, 0.45), (0.35, 0, 0.25), (0.08, 0.08)),
    ("lowerarm01.L", (0.35, 0, 0.25), (0.45, 0, 0.02), (0.07, 0.07)),
    ("upperarm01.R", (-0.18, 0, 0.45), (-0.35, 0, 0.25), (0.08, 0.08)),
    ("lowerarm01.R", (-0.35, 0, 0.25), (-0.45, 0, 0.02), (0.07, 0.07)),
]


def make_figure() -> SkinnedMesh:
    """Boxes along the limbs of the 18-joint skeleton, each rigidly skinned to its joint; cylindrical UVs."""
    parts, joints = [], []
    for joint, a, b, (w, d) in _BOXES:
        a, b = np.array(a) + LIFT, np.array(b) + LIFT
        axis = b - a
        T = trimesh.geometry.align_vectors([0.0, 0.0, 1.0], axis / np.linalg.norm(axis))
        T[:3, 3] = 0.5 * (a + b)
        box = trimesh.creation.box(extents=(w, d, np.linalg.norm(axis)), transform=T).subdivide().subdivide()
        parts.append(box)
        joints.append(np.full(len(box.vertices), NAMES.index(joint)))
    mesh = trimesh.util.concatenate(parts)
    V = np.asarray(mesh.vertices)
    faces = np.asarray(mesh.faces, np.int32)
    uvs = np.stack([np.arctan2(V[:, 1], V[:, 0]) / (2 * np.pi) + 0.5, (V[:, 2] - V[:, 2].min()) / np.ptp(V[:, 2])], 1)
    skeleton = Skeleton(tuple(NAMES), np.array(PARENTS), JOINTS + LIFT)
    return SkinnedMesh(skeleton, V, faces, np.concatenate(joints)[:, None].astype(np.int32),
                       np.ones((len(V), 1), np.float32), uvs=uvs.astype(np.float32), uv_faces=faces.copy())


def colours(vertices: np.ndarray) -> np.ndarray:
    """The figure's colour field [V, 3]: a gradient with checks (texture for the optical flow of the aligned reference)."""
    checks = 0.2 * np.sign(np.sin(30 * vertices[:, 0]) * np.sin(30 * vertices[:, 1] + 0.3) * np.sin(20 * vertices[:, 2]))
    return np.clip(0.5 + np.stack([vertices[:, 0], 1.5 * vertices[:, 1], 0.5 * (vertices[:, 2] - 0.9)], 1)
                   + checks[:, None], 0.05, 0.95)


def make_subject(path: Path, body: SkinnedMesh) -> Path:
    """FRAMES frames of the figure in random poses, seen by a camera walking around it; the painted mesh as the images."""
    rng = np.random.default_rng(3)
    J = body.skeleton.num_joints
    poses = rng.normal(0.0, 0.15, (FRAMES, J, 3))
    poses[:, 0] = 0.0
    trans = rng.normal(0.0, 0.03, (FRAMES, 3))
    K = intrinsics(40.0, 40.0, SIZE / 2, SIZE / 2)
    viewmat = np.stack([look_at((3.0 * np.sin(a), -3.0 * np.cos(a), 1.1), (0.0, 0.0, 0.9))
                        for a in np.linspace(-0.6, 0.6, FRAMES)])
    paint, images, masks = colours(body.vertices), [], []
    for i in range(FRAMES):
        frags = rasterize_mesh(body.pose(poses[i], trans[i]), body.faces, viewmat[i], K, SIZE, SIZE)
        mask = (frags.face_id >= 0).astype(np.float32)
        rgb = interpolate(frags, paint, body.faces) * mask[..., None] + (1 - mask[..., None]) * np.array(BACKGROUND)
        images.append(rgb.astype(np.float32))
        masks.append(mask)
    save_subject(path, body=body, poses=poses.astype(np.float32), trans=trans.astype(np.float32),
                 K=np.tile(K, (FRAMES, 1, 1)).astype(np.float32), viewmat=viewmat.astype(np.float32),
                 split=["train"] * TRAIN + ["test"] * (FRAMES - TRAIN), sequence=["walk"] * FRAMES, images=images,
                 masks=masks, width=SIZE, height=SIZE, body_model="test-boxes", background=BACKGROUND)
    return path


def make_avatar(path: Path, body: SkinnedMesh, subject: Path) -> Path:
    """Gaussians on the figure's vertices in its colours, skinned as the vertices are."""
    rgb = colours(body.vertices)
    save_avatar(path, skeleton=body.skeleton, body_model="test-boxes", source={"subject": str(subject), "step": STEP},
                gaussians={"positions": body.vertices.astype(np.float32),
                           "log_scales": np.full((body.num_vertices, 1), np.log(0.025), np.float32),
                           "rgb_logits": np.log(rgb / (1 - rgb)).astype(np.float32),
                           "opacities": np.full(body.num_vertices, 0.9, np.float32),
                           "skin_indices": body.skin_indices, "skin_weights": body.skin_weights})
    return path


def make_inputs(root: Path) -> SimpleNamespace:
    """Under ``root``: subject/, avatar/, other_avatar/ (5 joints), the shipped examiner.onnx and refiner_warp.onnx
    (warp+geo), and block Refiners (total downsampling 4): refiner.onnx (tex+geo, at 32x32), refiner_none.onnx
    (conditions "none"), refiner16.onnx (tex+geo at 16x16: the same function as refiner.onnx) and refiner16_fixed.onnx
    (the same with H and W fixed at 16, as an export before `trioman.size_multiple`)."""
    body = make_figure()
    subject = make_subject(root / "subject", body)
    avatar = make_avatar(root / "avatar", body, subject)
    write(root, name="other_avatar")
    models = {}
    for name, conditions, size, dims in (("refiner", "tex+geo", (32, 32), ("height", "width")),
                                         ("refiner_none", "none", (32, 32), ("height", "width")),
                                         ("refiner16", "tex+geo", (16, 16), ("height", "width")),
                                         ("refiner16_fixed", "tex+geo", (16, 16), (16, 16))):
        models[name] = block_refiner(root / f"{name}.onnx", multiple=4, size=size, dims=dims, conditions=conditions,
                                     config_hash=f"block-{conditions}")
    for kind, name in (("refiner", "refiner_warp"), ("examiner", "examiner")):
        models[name] = Path(shutil.copyfile(shipped_path(kind), root / f"{name}.onnx"))
    return SimpleNamespace(root=root, subject=subject, avatar=avatar, other_avatar=root / "other_avatar", **models)
