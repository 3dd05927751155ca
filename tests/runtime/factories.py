"""Small inputs of the runtime's tests, built with numpy alone (no torch): random skinned meshes, avatar folders
and edits of their files, the fields and images of a tiny subject on a 3-joint chain, and an 18-joint skeleton
with the joint names the motions look for."""

from __future__ import annotations

import json

import numpy as np

from trioman.runtime.cameras import look_at
from trioman.runtime.formats import load_avatar, save_avatar
from trioman.runtime.formats.avatar import sha256_file
from trioman.runtime.skeleton import Skeleton, SkinnedMesh

# --------------------------------------------------------------------------------------------------
# skinned meshes and avatar folders


def random_mesh(seed: int, J: int = 7, V: int = 40, K: int = 3) -> SkinnedMesh:
    rng = np.random.default_rng(seed)
    parents = np.array([-1] + [int(rng.integers(0, j)) for j in range(1, J)])
    sk = Skeleton(tuple(f"j{j}" for j in range(J)), parents, rng.normal(size=(J, 3)))
    w = rng.random((V, K)) + 0.01
    return SkinnedMesh(
        skeleton=sk,
        vertices=rng.normal(size=(V, 3)),
        faces=rng.integers(0, V, size=(10, 3)),
        skin_indices=rng.integers(0, J, size=(V, K)),
        skin_weights=(w / w.sum(1, keepdims=True)).astype(np.float32),
    )


def random_arrays(mesh, anisotropic=False, seed=0):
    rng = np.random.default_rng(seed)
    N = mesh.num_vertices
    arrays = {
        "positions": (mesh.vertices + 0.01 * rng.normal(size=(N, 3))).astype(np.float32),
        "log_scales": rng.uniform(-6, -3, size=(N, 3 if anisotropic else 1)).astype(np.float32),
        "rgb_logits": rng.normal(size=(N, 3)).astype(np.float32),
        "opacities": np.ones(N, np.float32),
        "skin_indices": mesh.skin_indices, "skin_weights": mesh.skin_weights,
    }
    if anisotropic:
        arrays["local_quats"] = (np.array([1, 0, 0, 0]) + 0.3 * rng.normal(size=(N, 4))).astype(np.float32)
    return arrays


def write(tmp_path, anisotropic=False, name="a", **kw):
    mesh = random_mesh(1, J=5, V=30)
    return save_avatar(tmp_path / name, skeleton=mesh.skeleton, gaussians=random_arrays(mesh, anisotropic),
                       body_model="test", pose_joints=["j1", "j2"], source={"run": "nowhere", "step": 3}, **kw), mesh


def resign(root, name):
    """Update avatar.json's sha256/bytes of ``name`` after a test edited it on purpose."""
    meta = json.loads((root / "avatar.json").read_text())
    meta["files"][name] = {"sha256": sha256_file(root / name), "bytes": (root / name).stat().st_size}
    (root / "avatar.json").write_text(json.dumps(meta))


def edit_npz(root, name, **changes):
    with np.load(root / name, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    for k, v in changes.items():
        if v is None:
            arrays.pop(k)
        else:
            arrays[k] = v
    np.savez(root / name, **arrays)
    resign(root, name)


def edit_json(root, **changes):
    meta = json.loads((root / "avatar.json").read_text())
    for k, v in changes.items():
        if v is None:
            meta.pop(k)
        else:
            meta[k] = v
    (root / "avatar.json").write_text(json.dumps(meta))


def transparent(avatar_dir):
    """Make every Gaussian of the avatar in ``avatar_dir`` all but invisible; returns the avatar loaded again."""
    with np.load(avatar_dir / "gaussians.npz") as z:
        opacities = np.full_like(z["opacities"], 1e-4)
    edit_npz(avatar_dir, "gaussians.npz", opacities=opacities)
    return load_avatar(avatar_dir)


# --------------------------------------------------------------------------------------------------
# a tiny subject: a 3-joint chain along z, N frames of W x H

W, H, N = 16, 12, 5


def make_body() -> SkinnedMesh:
    """A 3-joint chain along z with a thin strip of 4 triangles around it."""
    skeleton = Skeleton(
        joint_names=("root", "mid", "tip"),
        parents=np.array([-1, 0, 1], np.int32),
        joints=np.array([[0.0, 0.0, 0.9], [0.0, 0.0, 1.2], [0.0, 0.0, 1.5]]),
    )
    z = np.array([0.9, 1.2, 1.5])
    vertices = np.concatenate([np.stack([np.full(3, -0.1), np.zeros(3), z], 1), np.stack([np.full(3, 0.1), np.zeros(3), z], 1)])
    faces = np.array([[0, 3, 1], [1, 3, 4], [1, 4, 2], [2, 4, 5]], np.int32)
    skin_indices = np.array([[0, 1], [1, 0], [2, 1]] * 2, np.int32)
    skin_weights = np.array([[1.0, 0.0], [0.7, 0.3], [0.9, 0.1]] * 2, np.float32)
    uvs = np.array([[0, 0], [0, 0.5], [0, 1], [1, 0], [1, 0.5], [1, 1]], np.float32)
    return SkinnedMesh(skeleton, vertices, faces, skin_indices, skin_weights, uvs=uvs, uv_faces=faces.copy())


def make_fields(n: int = N) -> dict:
    rng = np.random.default_rng(0)
    body = make_body()
    poses_true = rng.normal(0, 0.3, (n, 3, 3)).astype(np.float32)
    K = np.tile(np.array([[20.0, 0, W / 2], [0, 20.0, H / 2], [0, 0, 1]], np.float32), (n, 1, 1))
    viewmat = np.stack([look_at((3.0 * np.cos(a), 3.0 * np.sin(a), 1.2 + 0.1 * a), (0.0, 0.0, 1.2)) for a in np.linspace(0, 1, n)]).astype(np.float32)
    return dict(
        body=body,
        poses=(poses_true + rng.normal(0, 0.05, poses_true.shape)).astype(np.float32),
        trans=rng.normal(0, 0.1, (n, 3)).astype(np.float32),
        K=K,
        viewmat=viewmat,
        split=["train"] * (n - 2) + ["test"] * 2,
        sequence=["walk"] * (n - 2) + ["dance"] * 2,
        width=W,
        height=H,
        body_model="test-chain",
        background=(1.0, 1.0, 1.0),
        phenotype={"height": 0.5, "weight": 0.25},
        generator={"tool": "pytest", "seed": np.int64(7), "pose_noise_sigma": 0.05},
        poses_true=poses_true,
    )


def make_images(n: int = N, seed: int = 1):
    rng = np.random.default_rng(seed)
    images = [rng.random((H, W, 3), dtype=np.float32) for _ in range(n)]
    masks = [rng.random((H, W), dtype=np.float32) for _ in range(n)]
    return images, masks


# --------------------------------------------------------------------------------------------------
# an 18-joint skeleton with the joint names the motions look for

NAMES = ["root", "pelvis.L", "upperleg01.L", "lowerleg01.L", "foot.L", "pelvis.R", "upperleg01.R", "lowerleg01.R",
         "foot.R", "spine05", "spine04", "spine01", "upperarm01.L", "lowerarm01.L", "upperarm01.R", "lowerarm01.R",
         "neck01", "head"]
PARENTS = [-1, 0, 1, 2, 3, 0, 5, 6, 7, 0, 9, 10, 11, 12, 11, 14, 11, 16]
JOINTS = np.array([[0, 0, 0], [0.1, 0, 0], [0.1, 0, -0.05], [0.12, 0, -0.45], [0.14, 0, -0.85], [-0.1, 0, 0],
                   [-0.1, 0, -0.05], [-0.12, 0, -0.45], [-0.14, 0, -0.85], [0, 0, 0.05], [0, 0, 0.2], [0, 0, 0.4],
                   [0.18, 0, 0.45], [0.35, 0, 0.25], [-0.18, 0, 0.45], [-0.35, 0, 0.25], [0, 0, 0.55], [0, 0, 0.65]])


# --------------------------------------------------------------------------------------------------
# Refiner ONNX files without torch (onnx builds them): a stand-in of a fully convolutional Refiner, and an older
# export's fixed-size file


def block_refiner(path, multiple: int = 8, size: tuple[int, int] = (32, 32), dims: tuple = ("height", "width"),
                  conditions: str = "none", config_hash: str | None = None):
    """A Refiner ONNX file with a total downsampling of ``multiple``, as `trioman export onnx` writes it (``dims``:
    the graph's H and W, symbolic names or ints) and its metadata (``trioman.size_multiple`` when ``dims`` are
    symbolic; ``trioman.config_hash`` when given): the inputs that ``conditions`` takes (coarse, reference, normal)
    are averaged, and each ``multiple`` x ``multiple`` block of that becomes its mean (AveragePool, then a nearest
    Resize back up), in every view of the output [B, V, 3, H, W]. Like the real Refiner it gives wrong shapes on sides
    that are not multiples; ``block_means`` is its output in numpy (conditions "none")."""
    import onnx
    from onnx import TensorProto, helper

    from trioman.runtime.onnx_models import REFINER_INPUTS, REFINER_VIEWS

    views = REFINER_VIEWS[conditions]
    inputs = list(REFINER_INPUTS[:views])
    scales = helper.make_tensor("scales", TensorProto.FLOAT, [4], [1.0, 1.0, float(multiple), float(multiple)])
    axes = helper.make_tensor("axes", TensorProto.INT64, [1], [1])
    initializers, nodes = [scales, axes], []
    first = "coarse"
    if views > 1:
        initializers.append(helper.make_tensor("share", TensorProto.FLOAT, [], [1.0 / views]))
        nodes += [helper.make_node("Sum", inputs, ["summed"]), helper.make_node("Mul", ["summed", "share"], ["mixed"])]
        first = "mixed"
    nodes += [helper.make_node("AveragePool", [first], ["pooled"], kernel_shape=[multiple, multiple],
                               strides=[multiple, multiple]),
              helper.make_node("Resize", ["pooled", "", "scales"], ["up"], mode="nearest"),
              helper.make_node("Unsqueeze", ["up", "axes"], ["refined" if views == 1 else "view"])]
    if views > 1:
        nodes.append(helper.make_node("Concat", ["view"] * views, ["refined"], axis=1))
    graph = helper.make_graph(nodes, "block_refiner",
                              [helper.make_tensor_value_info(name, TensorProto.FLOAT, ["batch", 3, *dims]) for name in inputs],
                              [helper.make_tensor_value_info("refined", TensorProto.FLOAT, ["batch", views, 3, *dims])],
                              initializers)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    meta = {"format": "trioman-onnx", "format_version": "1", "kind": "refiner", "precision": "fp32",
            "input_size": f"{size[0]},{size[1]}", "inputs": json.dumps(inputs), "outputs": '["refined"]',
            "conditions": conditions}
    if all(isinstance(d, str) for d in dims):
        meta["size_multiple"] = str(multiple)
    if config_hash is not None:
        meta["config_hash"] = config_hash
    for key, value in meta.items():
        model.metadata_props.add(key=f"trioman.{key}", value=value)
    onnx.checker.check_model(model)
    onnx.save(model, str(path))
    return path


def block_means(images: np.ndarray, multiple: int) -> np.ndarray:
    """``block_refiner``'s output [B, 1, 3, H, W] for HWC images [B, H, W, 3] whose sides are multiples of ``multiple``."""
    B, H, W, C = images.shape
    means = images.reshape(B, H // multiple, multiple, W // multiple, multiple, C).mean(axis=(2, 4))
    up = means.repeat(multiple, axis=1).repeat(multiple, axis=2)
    return up.transpose(0, 3, 1, 2)[:, None]


def fixed_size_copy(src, dst):
    """A copy of the Refiner ONNX file ``src`` as an export made before `trioman.size_multiple`: the graph's H and W
    static at its `trioman.input_size`, without the key."""
    import onnx

    proto = onnx.load(str(src))
    meta = {p.key: p.value for p in proto.metadata_props}
    H, W = (int(v) for v in meta["trioman.input_size"].split(","))
    for value in list(proto.graph.input) + list(proto.graph.output):
        dims = value.type.tensor_type.shape.dim
        dims[len(dims) - 2].dim_value, dims[len(dims) - 1].dim_value = H, W
    del proto.metadata_props[:]
    for key, value in meta.items():
        if key != "trioman.size_multiple":
            proto.metadata_props.add(key=key, value=value)
    onnx.save(proto, str(dst))
    return dst
