"""Trained GaussianAvatar -> the portable avatar format (docs/formats.md, "Avatar").

``bake(model)`` evaluates the triplane and the pose-independent MLPs once: what is left to compute per
pose is LBS (numpy) and, with pose dependence, the two small pose MLPs. ``pose_dependent_onnx(model)``
writes those as an ONNX graph (opset 17) with the pose-independent first-layer term
``feat_in(triplane features)`` folded in as a constant: input ``pose`` [J, 3] axis-angle, outputs
``d_offset`` [M, 3], ``d_log_scale`` [M, S], ``d_rgb`` [M, 3] at the model's ``pose_points`` (M = N, or
the coarse level's vertices, whose deltas the runtime carries to the Gaussians with the
``pose_interpolation`` arrays: format version 2). The graph is built node by node (the
pose features are Rodrigues + the 6D rotation, as ``GaussianAvatar.pose_features``), checked with
``onnx.checker`` (full check) and compared with torch under onnxruntime (``check_onnx_parity``).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import onnx
import torch
from onnx import TensorProto, helper, numpy_helper

from trioman.export.config import AvatarExportOptions
from trioman.runtime.formats.avatar import AVATAR_FOLDER, ONNX_INPUT, ONNX_OUTPUTS, save_avatar
from trioman.runtime.outputs import check_folder_target
from trioman.runtime.skeleton import Skeleton
from trioman.toolkit.avatar.model import GaussianAvatar

OPSET = 17
IR_VERSION = 8  # the IR of opset 17: loadable by every onnxruntime that runs opset 17
PARITY_ATOL = 1e-5
SMALL_THETA2 = 1e-12  # the Taylor branch of toolkit.rotations.axis_angle_to_matrix


class ParityError(RuntimeError):
    """The exported graph disagrees with the torch model."""


@torch.no_grad()
def bake(model: GaussianAvatar) -> dict[str, np.ndarray]:
    """The pose-independent attributes, pre-activation, as float32 numpy arrays (gaussians.npz)."""
    model = model.eval()
    feats = model.triplane(model.canonical)
    geo = model.geo_net(feats)
    s = 3 if model.cfg.anisotropic else 1
    out = {
        "positions": model.canonical + geo[:, :3],
        "log_scales": model.base_log_scale + geo[:, 3 : 3 + s],
        "rgb_logits": model.rgb_logits(feats),
        "opacities": torch.ones(model.num_gaussians),
    }
    if model.cfg.anisotropic:
        out["local_quats"] = geo[:, 3 + s :] + torch.tensor([1.0, 0.0, 0.0, 0.0])
    arrays = {k: v.float().numpy().copy() for k, v in out.items()}
    arrays["skin_indices"] = model.skin_indices.numpy().astype(np.int32)
    arrays["skin_weights"] = model.skin_weights.float().numpy().copy()
    return arrays


def pose_interpolation(model: GaussianAvatar) -> dict[str, np.ndarray]:
    """The gaussians.npz arrays that carry coarse pose deltas to the Gaussians: ``pose_indices`` [N, P] int32,
    ``pose_weights`` [N, P] float32 (the model's ``carry_pose_deltas``); empty without ``coarse_pose``."""
    if not model.coarse_pose:
        return {}
    return {"pose_indices": model.pose_indices.numpy().astype(np.int32),
            "pose_weights": model.pose_weights.float().numpy().copy()}


def skeleton_of(model: GaussianAvatar) -> Skeleton:
    return Skeleton(tuple(model.joint_names), np.asarray(model.parents), model.joints.double().numpy())


def pose_joint_names(model: GaussianAvatar) -> list[str]:
    return [model.joint_names[int(j)] for j in model.pose_joints]


# --------------------------------------------------------------------------------------------------
# the ONNX graph


class _Graph:
    def __init__(self) -> None:
        self.nodes: list[onnx.NodeProto] = []
        self.inits: list[onnx.TensorProto] = []
        self._n = 0

    def const(self, value: np.ndarray, name: str | None = None) -> str:
        self._n += 1
        name = name or f"c{self._n}"
        self.inits.append(numpy_helper.from_array(np.asarray(value), name))
        return name

    def op(self, op_type: str, *inputs: str, out: str | None = None, **attrs: Any) -> str:
        self._n += 1
        out = out or f"t{self._n}_{op_type.lower()}"
        self.nodes.append(helper.make_node(op_type, list(inputs), [out], **attrs))
        return out


def _linear_np(layer: torch.nn.Linear) -> tuple[np.ndarray, np.ndarray | None]:
    W = layer.weight.detach().float().numpy().T.copy()  # [in, out]
    b = None if layer.bias is None else layer.bias.detach().float().numpy().copy()
    return W, b


@torch.no_grad()
def pose_dependent_onnx(model: GaussianAvatar) -> onnx.ModelProto:
    """The pose-dependent MLPs as a checked ONNX model (see the module docstring)."""
    if not model.cfg.pose_dependent:
        raise ValueError("pose_dependent: this model has no pose-dependent MLPs")
    model = model.eval()
    J, M = len(model.joint_names), model.pose_points.shape[0]
    s = 3 if model.cfg.anisotropic else 1
    feats = model.triplane(model.pose_points)
    g = _Graph()

    # Pose features: Rodrigues on the conditioning joints, first two columns of R minus the identity's.
    sel = g.op("Gather", ONNX_INPUT, g.const(model.pose_joints.numpy().astype(np.int64)), axis=0)  # [Jc, 3]
    one = g.const(np.array(1.0, np.float32))
    x, y, z = (g.op("Gather", sel, g.const(np.array([i], np.int64)), axis=1) for i in range(3))  # [Jc, 1] each
    xx, yy, zz = g.op("Mul", x, x), g.op("Mul", y, y), g.op("Mul", z, z)
    xy, xz, yz = g.op("Mul", x, y), g.op("Mul", x, z), g.op("Mul", y, z)
    theta2 = g.op("Add", g.op("Add", xx, yy), zz)
    small = g.op("Less", theta2, g.const(np.array(SMALL_THETA2, np.float32)))
    theta = g.op("Sqrt", g.op("Where", small, one, theta2))
    a_small = g.op("Sub", one, g.op("Div", theta2, g.const(np.array(6.0, np.float32))))
    b_small = g.op("Sub", g.const(np.array(0.5, np.float32)), g.op("Div", theta2, g.const(np.array(24.0, np.float32))))
    a = g.op("Where", small, a_small, g.op("Div", g.op("Sin", theta), theta))
    b = g.op("Where", small, b_small, g.op("Div", g.op("Sub", one, g.op("Cos", theta)), g.op("Mul", theta, theta)))
    neg = lambda t: g.op("Neg", t)  # noqa: E731
    bm = lambda t: g.op("Mul", b, t)  # noqa: E731
    am = lambda t: g.op("Mul", a, t)  # noqa: E731
    # R = I + a K + b K^2 with K = [[0,-z,y],[z,0,-x],[-y,x,0]], K^2 = [[-yy-zz, xy, xz], [xy, -xx-zz, yz], [xz, yz, -xx-yy]].
    cols = [
        bm(neg(g.op("Add", yy, zz))),  # R00 - 1
        g.op("Add", am(z), bm(xy)),  # R10
        g.op("Add", am(neg(y)), bm(xz)),  # R20
        g.op("Add", am(neg(z)), bm(xy)),  # R01
        bm(neg(g.op("Add", xx, zz))),  # R11 - 1
        g.op("Add", am(x), bm(yz)),  # R21
    ]
    rot6 = g.op("Concat", *cols, axis=1)  # [Jc, 6]
    pf = g.op("Reshape", rot6, g.const(np.array([1, -1], np.int64)))  # [1, 6 Jc]

    def mlp(net, prefix: str) -> str:
        feat_term = net.feat_in(feats).float().numpy()  # [N, H] folded constant
        Wp, _ = _linear_np(net.pose_in)
        h = g.op("Add", g.const(feat_term, f"{prefix}.feat_term"), g.op("MatMul", pf, g.const(Wp, f"{prefix}.pose_in.weight")))
        h = g.op("Relu", h)
        lin1, lin2 = net.rest[0], net.rest[2]
        W1, b1 = _linear_np(lin1)
        h = g.op("Relu", g.op("Add", g.op("MatMul", h, g.const(W1, f"{prefix}.rest.0.weight")), g.const(b1, f"{prefix}.rest.0.bias")))
        W2, b2 = _linear_np(lin2)
        return g.op("Add", g.op("MatMul", h, g.const(W2, f"{prefix}.rest.2.weight")), g.const(b2, f"{prefix}.rest.2.bias"))

    dgeo = mlp(model.geo_offset_net, "geo_offset")  # [M, 3 + s]
    drgb = mlp(model.rgb_offset_net, "rgb_offset")  # [M, 3]
    g.op("Slice", dgeo, g.const(np.array([0], np.int64)), g.const(np.array([3], np.int64)), g.const(np.array([1], np.int64)), out=ONNX_OUTPUTS[0])
    g.op("Slice", dgeo, g.const(np.array([3], np.int64)), g.const(np.array([3 + s], np.int64)), g.const(np.array([1], np.int64)), out=ONNX_OUTPUTS[1])
    g.op("Identity", drgb, out=ONNX_OUTPUTS[2])

    graph = helper.make_graph(
        g.nodes, "trioman_pose_dependent",
        [helper.make_tensor_value_info(ONNX_INPUT, TensorProto.FLOAT, [J, 3])],
        [helper.make_tensor_value_info(ONNX_OUTPUTS[0], TensorProto.FLOAT, [M, 3]),
         helper.make_tensor_value_info(ONNX_OUTPUTS[1], TensorProto.FLOAT, [M, s]),
         helper.make_tensor_value_info(ONNX_OUTPUTS[2], TensorProto.FLOAT, [M, 3])],
        initializer=g.inits,
    )
    proto = helper.make_model(graph, opset_imports=[helper.make_opsetid("", OPSET)], producer_name="trioman")
    proto.ir_version = IR_VERSION
    onnx.checker.check_model(proto, full_check=True)
    return proto


@torch.no_grad()
def torch_pose_deltas(model: GaussianAvatar, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The torch model's pose-dependent deltas at ``pose`` [J, 3] at its ``pose_points`` (the reference for the
    ONNX graph) -> d_offset [M, 3], d_log_scale [M, S], d_rgb [M, 3]."""
    s = 3 if model.cfg.anisotropic else 1
    deltas = model.pose_deltas(model.pose_features(torch.as_tensor(np.asarray(pose), dtype=torch.float32)))
    d_offset, d_log_scale, d_rgb = deltas.split([3, s, 3], dim=1)
    return d_offset.numpy(), d_log_scale.numpy(), d_rgb.numpy()


def parity_poses(J: int, seed: int = 0) -> list[np.ndarray]:
    """Zero, tiny, near-pi and random poses [J, 3] float32."""
    rng = np.random.default_rng(seed)
    axes = rng.normal(size=(J, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    return [np.zeros((J, 3), np.float32), (axes * 1e-7).astype(np.float32), (axes * (np.pi - 1e-4)).astype(np.float32),
            *(rng.normal(scale=0.6, size=(J, 3)).astype(np.float32) for _ in range(3))]


def check_onnx_parity(model: GaussianAvatar, proto: onnx.ModelProto, atol: float = PARITY_ATOL, seed: int = 0) -> float:
    """Max |onnxruntime - torch| over the parity poses; raises ParityError above ``atol``."""
    import onnxruntime as ort

    opts = ort.SessionOptions()
    opts.log_severity_level = 3
    session = ort.InferenceSession(proto.SerializeToString(), sess_options=opts, providers=["CPUExecutionProvider"])
    worst = 0.0
    for k, pose in enumerate(parity_poses(len(model.joint_names), seed)):
        got = session.run(list(ONNX_OUTPUTS), {ONNX_INPUT: pose})
        want = torch_pose_deltas(model, pose)
        for name, a, b in zip(ONNX_OUTPUTS, got, want):
            err = float(np.abs(a - b).max())
            worst = max(worst, err)
            if not err <= atol:
                raise ParityError(f"pose_dependent.onnx: {name}: max |onnxruntime - torch| = {err:.3g} > {atol:g} at parity pose {k}")
    return worst


# --------------------------------------------------------------------------------------------------
# export


def export_model(model: GaussianAvatar, out: str | Path, *, body_model: str, pose_dependent: bool = True,
                 source: dict | None = None, posed: dict | None = None, overwrite: bool = False,
                 inputs: Sequence[str | Path | None] = ()):
    """Bake ``model`` and write an avatar folder (``overwrite`` and ``inputs``: ``save_avatar``'s).
    -> (runtime Avatar, info dict)."""
    t0 = time.perf_counter()
    proto, parity, gaussians = None, None, bake(model)
    if pose_dependent and model.cfg.pose_dependent:
        proto = pose_dependent_onnx(model)
        parity = check_onnx_parity(model, proto)
        gaussians |= pose_interpolation(model)
    avatar = save_avatar(
        out, skeleton=skeleton_of(model), gaussians=gaussians, body_model=body_model,
        pose_joints=pose_joint_names(model), pose_dependent_onnx=None if proto is None else proto.SerializeToString(),
        pose_points=model.pose_points.shape[0] if "pose_indices" in gaussians else None,
        source=source, posed=posed, overwrite=overwrite, inputs=inputs,
    )
    return avatar, {"seconds": time.perf_counter() - t0, "onnx_parity_max_abs": parity}


def export_avatar(run: str | Path, out: str | Path, checkpoint: str | Path | None = None,
                  pose_dependent: bool = AvatarExportOptions.pose_dependent,
                  ply_frames: Sequence[int] = AvatarExportOptions.ply_frames, overwrite: bool = False):
    """``trioman export avatar``: a run folder's (latest or named) checkpoint -> an avatar folder.

    ply_frames: subject frame indices; each adds posed_<I>.ply at that frame's pose and translation.
    -> (runtime Avatar, info dict).
    """
    from trioman.toolkit.evaluate import load_run
    from trioman.toolkit.loops.checkpoint import latest_checkpoint

    out = Path(out)
    check_folder_target(out, overwrite, AVATAR_FOLDER, (run, checkpoint))  # before any work; again with the subject
    ckpt = Path(checkpoint) if checkpoint else latest_checkpoint(Path(run))
    model, subject, _, step = load_run(run, ckpt)
    posed = {}
    for i in ply_frames:
        if not -subject.num_frames <= int(i) < subject.num_frames:
            raise ValueError(f"ply_frames: frame {i} out of range for the subject's {subject.num_frames} frames")
        i = int(i) % subject.num_frames
        posed[str(i)] = (np.asarray(subject.poses[i]), np.asarray(subject.trans[i]))
    source = {"run": str(Path(run).resolve()), "checkpoint": str(Path(ckpt).resolve()) if ckpt else None,
              "step": step, "subject": str(subject.root.resolve())}
    return export_model(model, out, body_model=subject.body_model, pose_dependent=pose_dependent, source=source,
                        posed=posed, overwrite=overwrite, inputs=(run, ckpt, subject.root))
