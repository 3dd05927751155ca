"""Tiny captures written in each real layout (X-Humans, NeuMan with COLMAP text, Custom, SMPLer-X fits).

64 x 64 frames: a coloured disc (the person) on a grey background. Every frame's SMPL-X parameters are
random, with the pelvis placed 3 m in front of the camera on its optical axis, so the pelvis projects to
the principal point; ``Scene`` keeps what was written so tests can pose smplx on it.
"""

from __future__ import annotations

import json
import pickle
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from trioman.runtime.rotations import axis_angle_to_matrix, matrix_to_quat

SIZE = 64
FOCAL = (70.0, 72.0)
PRINCPT = (31.0, 33.0)
NUM_BETAS = 100


@dataclass
class Scene:
    """What a layout writer wrote: per frame the SMPL-X parameters (SMPL-X's names) and world -> camera."""

    betas: np.ndarray
    frames: list[dict] = field(default_factory=list)  # {"name", "split", "params", "R", "t", "in_camera"}


def rest_pelvis(model_dir: Path, betas: np.ndarray) -> np.ndarray:
    """The shaped rest pelvis in SMPL-X's frame, from the model file directly."""
    with np.load(model_dir / "SMPLX_MALE.npz", allow_pickle=False) as f:
        v = f["v_template"] + f["shapedirs"][:, :, : len(betas)] @ betas
        return f["J_regressor"][0] @ v


def _params(rng: np.random.Generator, pelvis_cam: np.ndarray, R: np.ndarray, t: np.ndarray, j0: np.ndarray,
            in_camera: bool) -> dict:
    """Random SMPL-X parameters whose pelvis lands at ``pelvis_cam`` in the camera frame."""
    target = pelvis_cam if in_camera else R.T @ (pelvis_cam - t)  # camera or world frame
    root = rng.normal(scale=0.3, size=3) + (0.0, np.pi, 0.0)  # facing the camera, roughly
    return {"root_pose": root.tolist(), "body_pose": rng.normal(scale=0.3, size=(21, 3)).tolist(),
            "jaw_pose": rng.normal(scale=0.1, size=3).tolist(), "leye_pose": rng.normal(scale=0.1, size=3).tolist(),
            "reye_pose": rng.normal(scale=0.1, size=3).tolist(), "lhand_pose": rng.normal(scale=0.3, size=(15, 3)).tolist(),
            "rhand_pose": rng.normal(scale=0.3, size=(15, 3)).tolist(), "expr": rng.normal(size=50).tolist(),
            "trans": (target - j0).tolist()}


def _camera(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    R = axis_angle_to_matrix(rng.normal(scale=0.4, size=3))
    return R, rng.normal(size=3)


def _image_and_mask(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    yy, xx = np.mgrid[:SIZE, :SIZE]
    mask = ((yy - 33) ** 2 + (xx - 31) ** 2 < 18**2).astype(np.uint8) * 255
    img = np.full((SIZE, SIZE, 3), 128, np.uint8)
    img[mask > 0] = rng.integers(0, 256, 3)
    return img, mask


def _png(path: Path, img: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), img)


def _json(path: Path, obj) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(obj))


def _identity(folder: Path, rng: np.random.Generator) -> Scene:
    betas = rng.normal(scale=0.5, size=NUM_BETAS)
    _json(folder / "smplx_optimized" / "shape_param.json", betas.tolist())
    return Scene(betas=betas)


def _pelvis(model_dir: Path, scene: Scene) -> np.ndarray:
    return rest_pelvis(model_dir, scene.betas)


def write_xhumans(root: Path, model_dir: Path, seed: int = 0) -> Scene:
    """ROOT/00028/{train/Take1, train/Take2, test/Take9} with 2 frames each; fits as X-Humans' pickles."""
    rng = np.random.default_rng(seed)
    subj = root / "00028"
    scene = _identity(subj, rng)
    j0 = _pelvis(model_dir, scene)
    intr = np.array([[FOCAL[0], 0, PRINCPT[0]], [0, FOCAL[1], PRINCPT[1]], [0, 0, 1]])
    for split, take in (("train", "Take1"), ("train", "Take2"), ("test", "Take9")):
        d = subj / split / take
        extr = []
        for idx in (1, 2):
            R, t = _camera(rng)
            E = np.eye(4)
            E[:3, :3], E[:3, 3] = R, t
            extr.append(E)
            p = _params(rng, np.array([0.0, 0.0, 3.0]), R, t, j0, in_camera=False)
            img, mask = _image_and_mask(rng)
            _png(d / "render" / "image" / f"color_{idx:06d}.png", img)
            depth = np.where(mask > 0, 2.5, 8.0).astype(np.float32)
            (d / "render" / "depth").mkdir(parents=True, exist_ok=True)
            cv2.imwrite(str(d / "render" / "depth" / f"depth_{idx:06d}.tiff"), depth)
            fit = {"global_orient": np.array(p["root_pose"]), "body_pose": np.array(p["body_pose"]).reshape(63),
                   "left_hand_pose": np.array(p["lhand_pose"]).reshape(45),
                   "right_hand_pose": np.array(p["rhand_pose"]).reshape(45), "jaw_pose": np.array(p["jaw_pose"]),
                   "leye_pose": np.array(p["leye_pose"]), "reye_pose": np.array(p["reye_pose"]),
                   "transl": np.array(p["trans"]), "betas": np.zeros(10), "expression": np.zeros(10)}
            (d / "SMPLX").mkdir(parents=True, exist_ok=True)
            with open(d / "SMPLX" / f"mesh-f{idx:05d}_smplx.pkl", "wb") as f:
                pickle.dump(fit, f)
            scene.frames.append({"name": f"{take}_{idx:06d}", "split": split, "params": p, "R": R, "t": t,
                                 "in_camera": False})
        np.savez(d / "render" / "cameras.npz", intrinsic=intr, extrinsic=np.stack(extr))
    return scene


def _colmap(sparse: Path, cams: dict[str, tuple[np.ndarray, np.ndarray]]) -> None:
    sparse.mkdir(parents=True, exist_ok=True)
    (sparse / "cameras.txt").write_text(
        "# Camera list with one line of data per camera:\n"
        f"1 PINHOLE {SIZE} {SIZE} {FOCAL[0]} {FOCAL[1]} {PRINCPT[0]} {PRINCPT[1]}\n")
    lines = ["# Image list with two lines of data per image:"]
    for i, (name, (R, t)) in enumerate(cams.items(), 1):
        q = matrix_to_quat(R)
        lines.append(f"{i} {' '.join(repr(float(v)) for v in q)} {' '.join(repr(float(v)) for v in t)} 1 {name}")
        lines.append("")  # no 2D points
    (sparse / "images.txt").write_text("\n".join(lines) + "\n")
    (sparse / "points3D.txt").write_text("# empty\n")


def write_neuman(root: Path, model_dir: Path, seed: int = 1) -> Scene:
    """ROOT/bike: 7 frames, train 0-3, test 4-5, frame 6 in neither (NeuMan's val split); COLMAP text."""
    rng = np.random.default_rng(seed)
    seq = root / "bike"
    scene = _identity(seq, rng)
    j0 = _pelvis(model_dir, scene)
    cams = {}
    for idx in range(7):
        name = f"{idx:05d}"
        R, t = _camera(rng)
        cams[f"{name}.png"] = (R, t)
        p = _params(rng, np.array([0.0, 0.0, 3.0]), R, t, j0, in_camera=True)
        img, mask = _image_and_mask(rng)
        _png(seq / "images" / f"{name}.png", img)
        _png(seq / "masks" / f"{name}.png", mask)
        _png(seq / "segmentations" / f"{name}.png", 255 - mask)
        _json(seq / "smplx_optimized" / "smplx_params" / f"{name}.json", p)
        if idx < 6:
            scene.frames.append({"name": name, "split": "train" if idx < 4 else "test", "params": p, "R": R, "t": t,
                                 "in_camera": True})
    _colmap(seq / "sparse", cams)
    (seq / "train_split.txt").write_text("".join(f"{i:05d}.png\n" for i in range(4)))
    (seq / "test_split.txt").write_text("00004.png\n00005.png\n")
    (seq / "val_split.txt").write_text("00006.png\n")
    return scene


def write_custom(root: Path, model_dir: Path, seed: int = 2) -> Scene:
    """ROOT/myvideo: 4 frames (3 train, 1 test), virtual cameras in cam_params/ (R = I, t = 0)."""
    rng = np.random.default_rng(seed)
    vid = root / "myvideo"
    scene = _identity(vid, rng)
    j0 = _pelvis(model_dir, scene)
    for idx in range(4):
        R, t = np.eye(3), np.zeros(3)
        p = _params(rng, np.array([0.0, 0.0, 3.0]), R, t, j0, in_camera=True)
        img, mask = _image_and_mask(rng)
        _png(vid / "frames" / f"{idx}.png", img)
        _png(vid / "masks" / f"{idx}.png", mask)
        _json(vid / "smplx_optimized" / "smplx_params_smoothed" / f"{idx}.json", p)
        _json(vid / "cam_params" / f"{idx}.json", {"R": R.tolist(), "t": t.tolist(), "focal": list(FOCAL),
                                                   "princpt": list(PRINCPT)})
        scene.frames.append({"name": str(idx), "split": "train" if idx < 3 else "test", "params": p, "R": R, "t": t,
                             "in_camera": True})
    (vid / "frame_list_train.txt").write_text("0\n1\n2\n")
    (vid / "frame_list_test.txt").write_text("3\n")
    (vid / "frame_list_all.txt").write_text("0\n1\n2\n3\n")
    return scene


def write_smplerx(root: Path, model_dir: Path, seed: int = 3) -> Scene:
    """ROOT/frames/%05d.png, ROOT/masks/, ROOT/fits/{smplx,meta}/%05d_0.npz|json: 5 frames (the 5th is test)."""
    rng = np.random.default_rng(seed)
    betas = rng.normal(scale=0.5, size=10)
    scene = Scene(betas=betas)
    with np.load(model_dir / "SMPLX_NEUTRAL.npz", allow_pickle=False) as f:
        j0 = f["J_regressor"][0] @ (f["v_template"] + f["shapedirs"][:, :, :10] @ betas)
    for idx in range(5):
        name = f"{idx:05d}"
        p = _params(rng, np.array([0.0, 0.0, 3.0]), np.eye(3), np.zeros(3), j0, in_camera=True)
        img, mask = _image_and_mask(rng)
        _png(root / "frames" / f"{name}.png", img)
        _png(root / "masks" / f"{name}.png", mask)
        (root / "fits" / "smplx").mkdir(parents=True, exist_ok=True)
        np.savez(root / "fits" / "smplx" / f"{name}_0.npz", global_orient=np.array(p["root_pose"])[None],
                 body_pose=np.array(p["body_pose"]), left_hand_pose=np.array(p["lhand_pose"]),
                 right_hand_pose=np.array(p["rhand_pose"]), jaw_pose=np.array(p["jaw_pose"])[None],
                 betas=betas[None], expression=rng.normal(size=(1, 10)), transl=np.array(p["trans"])[None])
        _json(root / "fits" / "meta" / f"{name}_0.json", {"focal": list(FOCAL), "princpt": list(PRINCPT)})
        p = {**p, "leye_pose": [0.0] * 3, "reye_pose": [0.0] * 3}
        scene.frames.append({"name": name, "split": "test" if idx == 4 else "train", "params": p, "R": np.eye(3),
                             "t": np.zeros(3), "in_camera": True})
    return scene
