"""Tiny captures laid out as the upstream code writes them, for the importer tests.

Upstream revisions read: ExAvatar_RELEASE d452687 (its ``fitting/`` and ``avatar/data/*``) and its X-Humans branch
4afd138 (the avatar code for X-Humans: ``data/XHumans/XHumans.py``, ``main/config.py``), ml-neuman 0149d25 (the NeuMan
preprocessing and readers), X-Avatar 7a071b6 (X-Humans' release: ``data_process/README.md``,
``code/lib/dataset/XHumans_rgbd.py``). Each writer names, in a comment, the upstream file and line whose
output it reproduces; nothing here is upstream code.

64 x 64 frames: a coloured disc (the person) on a grey background. The person stands in the capture's world
along a known up direction (``Scene.up``): a random direction for COLMAP worlds (which have no up), about
-y for a camera frame (virtual cameras, SMPLer-X), +y for X-Humans. Cameras look at the pelvis from 3 m
with their up near the person's, so the pelvis projects to the principal point. ``Scene`` keeps what was
written, so tests can pose smplx on it.
"""

from __future__ import annotations

import json
import pickle
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from trioman.runtime.rotations import axis_angle_to_matrix, matrix_to_axis_angle, matrix_to_quat

SIZE = 64
FOCAL = (70.0, 72.0)
PRINCPT = (31.0, 33.0)
NUM_BETAS = 100
DISTANCE = 3.0  # camera -> pelvis, metres
E_Y = np.array([0.0, 1.0, 0.0])
NUM_FLAME_VERTICES = 5023  # FLAME's vertices, which ExAvatar's face_offset covers inside SMPL-X's 10,475


@dataclass
class Scene:
    """What a layout writer wrote: the identity, the capture world's up, and per frame the SMPL-X parameters
    (ExAvatar's names), the camera (world -> camera R, t; focal, princpt) and the frame's name and split."""

    betas: np.ndarray
    up: np.ndarray = field(default_factory=lambda: E_Y.copy())
    gender: str = "male"
    face_offset: np.ndarray | None = None  # [10475, 3] SMPL-X frame
    joint_offset: np.ndarray | None = None  # [55, 3]
    frames: list[dict] = field(default_factory=list)  # {"name", "split", "params", "R", "t", "in_camera", "focal", "princpt"}
    by_source: dict[str, "Scene"] = field(default_factory=dict)  # X-Humans: the scene of each fit source written


def rest_pelvis(model_dir: Path, betas: np.ndarray, face_offset: np.ndarray | None = None,
                gender: str = "male") -> np.ndarray:
    """The shaped rest pelvis in SMPL-X's frame, from the model file directly (face offset on the template)."""
    with np.load(model_dir / f"SMPLX_{gender.upper()}.npz", allow_pickle=False) as f:
        v = f["v_template"] + (0 if face_offset is None else face_offset) + f["shapedirs"][:, :, : len(betas)] @ betas
        return f["J_regressor"][0] @ v


# --------------------------------------------------------------------------------------------------
# geometry of a standing person and cameras around them


def _rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation taking unit vector a onto unit vector b."""
    axis = np.cross(a, b)
    s, c = np.linalg.norm(axis), float(a @ b)
    if s < 1e-12:
        if c > 0:
            return np.eye(3)
        perp = np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0])
        return axis_angle_to_matrix(np.pi * perp / np.linalg.norm(perp))
    return axis_angle_to_matrix(axis / s * np.arctan2(s, c))


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def _standing_root(rng: np.random.Generator, up: np.ndarray) -> np.ndarray:
    """World root rotation of a person standing along ``up``: SMPL-X's +y onto up, any heading, a slight lean."""
    heading = axis_angle_to_matrix(np.array([0.0, rng.uniform(-np.pi, np.pi), 0.0]))
    lean = axis_angle_to_matrix(rng.normal(scale=0.05, size=3))
    return _rotation_between(E_Y, up) @ lean @ heading


def _look_at(rng: np.random.Generator, pelvis: np.ndarray, up: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World -> camera (R, t) of a camera DISTANCE m from the pelvis, looking at it slightly from above with a
    few degrees of roll: the pelvis lands at (0, 0, DISTANCE) in the camera."""
    h = rng.normal(size=3)
    z = _unit(_unit(h - (h @ up) * up) - rng.uniform(0.0, 0.3) * up)  # forward
    cam_up = axis_angle_to_matrix(z * rng.normal(scale=0.05)) @ up  # rolled
    y = -_unit(cam_up - (cam_up @ z) * z)  # down
    R = np.stack([np.cross(y, z), y, z])
    return R, -R @ (pelvis - DISTANCE * z)


def _fit(rng: np.random.Generator, root_world: np.ndarray, pelvis_world: np.ndarray, R: np.ndarray, t: np.ndarray,
         j0: np.ndarray, in_camera: bool) -> dict:
    """Random SMPL-X parameters with ExAvatar's keys and shapes (ExAvatar_RELEASE fitting/main/fit.py lines
    169-177: root_pose [3], body_pose [21, 3], jaw/leye/reye_pose [3], l/rhand_pose [15, 3], expr [50], trans [3],
    trans being smplx's transl), in the camera frame (``in_camera``) or the world."""
    root = R @ root_world if in_camera else root_world
    pelvis = R @ pelvis_world + t if in_camera else pelvis_world
    return {"root_pose": matrix_to_axis_angle(root).tolist(), "body_pose": rng.normal(scale=0.3, size=(21, 3)).tolist(),
            "jaw_pose": rng.normal(scale=0.1, size=3).tolist(), "leye_pose": rng.normal(scale=0.1, size=3).tolist(),
            "reye_pose": rng.normal(scale=0.1, size=3).tolist(), "lhand_pose": rng.normal(scale=0.3, size=(15, 3)).tolist(),
            "rhand_pose": rng.normal(scale=0.3, size=(15, 3)).tolist(), "expr": rng.normal(size=50).tolist(),
            "trans": (pelvis - j0).tolist()}


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


def _exavatar_identity(folder: Path, rng: np.random.Generator, model_dir: Path, offsets: bool = True) -> Scene:
    """``smplx_optimized/`` identity files as ExAvatar_RELEASE fitting/main/fit.py writes them (lines 178-193):
    shape_param.json [100]; face_offset.json [10475, 3], zero outside FLAME's face vertices (fitting/common/utils/
    smpl_x.py get_face_offset, line 77); joint_offset.json [55, 3], zero at the pelvis and hips (get_joint_offset,
    line 83); locator_offset.json [55, 3], non-zero only at the hips (get_locator_offset, line 91)."""
    betas = rng.normal(scale=0.5, size=NUM_BETAS)
    opt = folder / "smplx_optimized"
    _json(opt / "shape_param.json", betas.tolist())
    scene = Scene(betas=betas)
    if offsets:
        face = np.zeros((10475, 3))
        face[rng.choice(10475, NUM_FLAME_VERTICES, replace=False)] = rng.normal(scale=0.005, size=(NUM_FLAME_VERTICES, 3))
        joint = rng.normal(scale=0.01, size=(55, 3))
        joint[[0, 1, 2]] = 0.0  # pelvis, left hip, right hip
        locator = np.zeros((55, 3))
        locator[[1, 2]] = rng.normal(scale=0.01, size=(2, 3))
        _json(opt / "face_offset.json", face.tolist())
        _json(opt / "joint_offset.json", joint.tolist())
        _json(opt / "locator_offset.json", locator.tolist())
        scene.face_offset, scene.joint_offset = face, joint
    return scene


def _pelvis(model_dir: Path, scene: Scene) -> np.ndarray:
    return rest_pelvis(model_dir, scene.betas, scene.face_offset, scene.gender)


def _colmap(sparse: Path, cams: dict[str, tuple[np.ndarray, np.ndarray]], rng: np.random.Generator) -> None:
    """COLMAP's text model (cameras.txt, images.txt, points3D.txt) with the headers ml-neuman's reader asserts
    (ml-neuman data_io/colmap_helper.py, read_cameras line 90, read_images_meta line 120): one shared PINHOLE
    camera (8 fields, as ExAvatar's loaders split it: avatar/data/NeuMan/NeuMan.py line 42), images in
    registration order (not by name), quaternions of either sign (q and -q are the same rotation; COLMAP does
    not make qw >= 0), a line of 2D points after each image line; points3D.txt with a few points (ExAvatar's
    NeuMan loader reads it: avatar/data/NeuMan/NeuMan.py line 93)."""
    sparse.mkdir(parents=True, exist_ok=True)
    (sparse / "cameras.txt").write_text(
        "# Camera list with one line of data per camera:\n#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n"
        f"# Number of cameras: 1\n1 PINHOLE {SIZE} {SIZE} {FOCAL[0]} {FOCAL[1]} {PRINCPT[0]} {PRINCPT[1]}\n")
    order = rng.permutation(len(cams))
    items = list(cams.items())
    lines = ["# Image list with two lines of data per image:", "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME",
             "#   POINTS2D[] as (X, Y, POINT3D_ID)", f"# Number of images: {len(cams)}, mean observations per image: 3.0"]
    for image_id, k in enumerate(order, 1):
        name, (R, t) = items[k]
        q = matrix_to_quat(R) * (-1.0 if image_id % 2 else 1.0)
        lines.append(f"{image_id} {' '.join(repr(float(v)) for v in q)} {' '.join(repr(float(v)) for v in t)} 1 {name}")
        lines.append("12.5 20.25 1 30.0 8.5 -1 40.75 33.0 2")
    (sparse / "images.txt").write_text("\n".join(lines) + "\n")
    (sparse / "points3D.txt").write_text(
        "# 3D point list with one line of data per point:\n"
        "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)\n"
        "# Number of points: 2, mean track length: 1.0\n1 0.5 0.1 4.0 120 130 140 0.5 1 0\n"
        "2 -0.3 0.2 5.0 90 80 70 0.4 2 2\n")


def neuman_splits(num_frames: int) -> dict[str, list[int]]:
    """ml-neuman's split of a capture (data_io/neuman_helper.py create_split_files, line 149): every k-th capture
    in name order is held out from k // 2 (k = N / (N // 5)), the first half of those test, the rest val."""
    step = int(num_frames / (num_frames // 5))
    held = list(range(step // 2, num_frames, step))
    return {"train": [i for i in range(num_frames) if i not in held], "test": held[: len(held) // 2],
            "val": held[len(held) // 2:]}


# --------------------------------------------------------------------------------------------------
# the layouts


def write_neuman(root: Path, model_dir: Path, seed: int = 1, num_frames: int = 10) -> Scene:
    """ROOT/bike as ExAvatar's fitting leaves a NeuMan capture: 10 frames, ml-neuman's splits (train 8, test
    frame 2, val frame 7), COLMAP text in a world with a random up."""
    rng = np.random.default_rng(seed)
    seq = root / "bike"
    scene = _exavatar_identity(seq, rng, model_dir)
    scene.up = _unit(rng.normal(size=3))
    j0 = _pelvis(model_dir, scene)
    splits = neuman_splits(num_frames)
    split_of = {i: s for s, frames in splits.items() for i in frames}
    start = rng.normal(size=3) * 2
    cams = {}
    for idx in range(num_frames):
        pelvis = start + 0.1 * idx * _unit(np.cross(scene.up, [1.0, 0.0, 0.0]))  # walking
        R, t = _look_at(rng, pelvis, scene.up)
        p = _fit(rng, _standing_root(rng, scene.up), pelvis, R, t, j0, in_camera=True)
        img, mask = _image_and_mask(rng)
        _png(seq / "images" / f"{idx:05d}.png", img)  # ml-neuman preprocess/save_video_frames.py line 50: zfill(5)
        _png(seq / "masks" / f"{idx}.png", mask)  # ExAvatar_RELEASE fitting/tools/code_to_copy/run_sam.py line 75
        # NeuMan's Detectron2 masks, 255 = background: ml-neuman cameras/captures.py (mask), and ExAvatar_RELEASE
        # avatar/tools/eval_neuman.py line 48 ('%05d.png', 1 - mask / 255)
        _png(seq / "segmentations" / f"{idx:05d}.png", 255 - mask)
        # ExAvatar_RELEASE fitting/main/fit.py line 168: str(frame_idx) + '.json', unpadded
        _json(seq / "smplx_optimized" / "smplx_params" / f"{idx}.json", p)
        cams[f"{idx:05d}.png"] = (R, t)
        if split_of[idx] != "val":
            scene.frames.append({"name": f"{idx:05d}", "split": split_of[idx], "params": p, "R": R, "t": t,
                                 "in_camera": True, "focal": FOCAL, "princpt": PRINCPT})
    _colmap(seq / "sparse", cams, rng)
    for split, frames in splits.items():  # ml-neuman neuman_helper.py create_split_files: "%s\n" of the image name
        (seq / f"{split}_split.txt").write_text("".join(f"{i:05d}.png\n" for i in frames))
    return scene


def write_custom(root: Path, model_dir: Path, seed: int = 2, colmap: bool = False) -> Scene:
    """ROOT/myvideo as ExAvatar's tools leave a custom video: frames 0-3 (3 train, 1 test). Virtual cameras in
    cam_params/ (R = I, t = 0: the world is the camera frame, y down) or, with ``colmap``, COLMAP text naming the
    images image{N}.jpg in a world with a random up."""
    rng = np.random.default_rng(seed)
    vid = root / "myvideo"
    scene = _exavatar_identity(vid, rng, model_dir)
    tilt = axis_angle_to_matrix(np.array([rng.uniform(0.1, 0.3), 0.0, 0.0]))  # the camera looks slightly down
    scene.up = _unit(rng.normal(size=3)) if colmap else tilt @ -E_Y
    j0 = _pelvis(model_dir, scene)
    # virtual cameras: ExAvatar_RELEASE fitting/tools/make_virtual_cam_params.py lines 26-27 (focal 2000, image centre)
    focal, princpt = (FOCAL, PRINCPT) if colmap else ((2000.0, 2000.0), (SIZE / 2, SIZE / 2))
    cams = {}
    for idx in range(4):
        pelvis = np.array([0.0, 0.0, DISTANCE]) + (0.05 * idx * np.cross(scene.up, [0.0, 0.0, 1.0]) if colmap else 0.0)
        R, t = _look_at(rng, pelvis, scene.up) if colmap else (np.eye(3), np.zeros(3))
        p = _fit(rng, _standing_root(rng, scene.up), pelvis, R, t, j0, in_camera=True)
        img, mask = _image_and_mask(rng)
        _png(vid / "frames" / f"{idx}.png", img)  # ExAvatar_RELEASE fitting/tools/extract_frames.py line 24
        _png(vid / "masks" / f"{idx}.png", mask)  # fitting/tools/code_to_copy/run_sam.py line 75
        # fitting/tools/smooth_smplx_params.py line 167: smplx_params_smoothed/str(frame_idx) + '.json'
        _json(vid / "smplx_optimized" / "smplx_params_smoothed" / f"{idx}.json", p)
        if colmap:
            cams[f"image{idx}.jpg"] = (R, t)  # fitting/tools/code_to_copy/run_colmap.py line 32
        else:
            _json(vid / "cam_params" / f"{idx}.json", {"R": R.tolist(), "t": t.tolist(), "focal": list(focal),
                                                       "princpt": list(princpt)})
        scene.frames.append({"name": str(idx), "split": "train" if idx < 3 else "test", "params": p, "R": R, "t": t,
                             "in_camera": True, "focal": focal, "princpt": princpt})
    if colmap:
        _colmap(vid / "sparse", cams, rng)
    # fitting/README.md: frame_list_{all,train,test}.txt, 'a frame index and a new line'
    (vid / "frame_list_train.txt").write_text("0\n1\n2\n")
    (vid / "frame_list_test.txt").write_text("3\n")
    (vid / "frame_list_all.txt").write_text("0\n1\n2\n3\n")
    return scene


def _exavatar_take_fits(take: Path, scene: Scene) -> None:
    """ExAvatar's fitting output of one X-Humans take, where fitting/tools/run.py line 92 moves it (output/result/
    SUBJECT/* into the --root_path, here the take): smplx_optimized/shape_param.json, face_offset.json,
    joint_offset.json, locator_offset.json (fitting/main/fit.py lines 178-193), copied from the subject's identity;
    the per-frame fits are written by the caller."""
    opt = take / "smplx_optimized"
    _json(opt / "shape_param.json", scene.betas.tolist())
    _json(opt / "face_offset.json", scene.face_offset.tolist())
    _json(opt / "joint_offset.json", scene.joint_offset.tolist())
    _json(opt / "locator_offset.json", np.zeros((55, 3)).tolist())


def write_xhumans(root: Path, model_dir: Path, seed: int = 0, exavatar_takes: tuple[str, ...] = (),
                  gender: str = "male") -> Scene:
    """ROOT/00028 as X-Avatar releases X-Humans (data_process/README.md lines 33-55): gender.txt and
    mean_shape_smplx.npy (10 betas) under the subject; {train/Take1, train/Take2, test/Take9} with 2 frames each:
    render/image/color_%06d.png, render/depth/depth_%06d.tiff, render/cameras.npz, SMPLX/mesh-f%05d_smplx.pkl (world
    frame, y up, fitted to X-Humans' own body: ``gender``, per-frame betas equal to the mean shape).

    Beside it, ExAvatar's identity under the subject (smplx_optimized/, male, 100 betas, face and joint offsets), as
    its X-Humans branch reads it with X-Humans' own fits (data/XHumans/XHumans.py lines 57-65 and 85-94,
    main/config.py line 30): a body those fits were not made for. The takes in ``exavatar_takes`` also hold ExAvatar's
    fitting output (``_exavatar_take_fits``; smplx_optimized/smplx_params/N.json, fit.py line 168, N the number of
    color_N.png as fitting/data/XHumans/XHumans.py line 46 parses it), in the camera frame of each image's camera
    (XHumans.py lines 104-111 turn the root into it; lines 119-136 place the translation in it), for the same person
    in the same place.

    Returns the scene of the fits a plain import reads: ExAvatar's when every take holds them, else X-Humans';
    ``by_source`` holds both (ExAvatar's with the fitted takes' frames only)."""
    rng = np.random.default_rng(seed)
    subj = root / "00028"
    exavatar = _exavatar_identity(subj, rng, model_dir)  # subject-level: ExAvatar's X-Humans branch layout
    mean_shape = rng.normal(scale=0.5, size=10)
    xhumans = Scene(betas=mean_shape, gender=gender)
    subj.mkdir(parents=True, exist_ok=True)
    # X-Avatar code/lib/dataset/XHumans_rgbd.py lines 52-53: np.load('mean_shape_smplx.npy'), gender.txt's first line
    (subj / "gender.txt").write_text(gender)
    np.save(subj / "mean_shape_smplx.npy", mean_shape)
    j0_xh, j0_ex = _pelvis(model_dir, xhumans), _pelvis(model_dir, exavatar)
    intr = np.array([[FOCAL[0], 0, PRINCPT[0]], [0, FOCAL[1], PRINCPT[1]], [0, 0, 1]])
    for split, take in (("train", "Take1"), ("train", "Take2"), ("test", "Take9")):
        d = subj / split / take
        if take in exavatar_takes:
            _exavatar_take_fits(d, exavatar)
        extr = []
        for idx in (1, 2):
            pelvis = np.array([0.0, 0.9, 0.0]) + rng.normal(scale=0.2, size=3)
            R, t = _look_at(rng, pelvis, xhumans.up)
            E = np.eye(4)
            E[:3, :3], E[:3, 3] = R, t
            extr.append(E)
            root_world = _standing_root(rng, xhumans.up)
            p = _fit(rng, root_world, pelvis, R, t, j0_xh, in_camera=False)
            img, mask = _image_and_mask(rng)
            _png(d / "render" / "image" / f"color_{idx:06d}.png", img)
            depth = np.where(mask > 0, 2.5, 8.0).astype(np.float32)
            (d / "render" / "depth").mkdir(parents=True, exist_ok=True)
            cv2.imwrite(str(d / "render" / "depth" / f"depth_{idx:06d}.tiff"), depth)
            # X-Avatar data_process/README.md lines 53-54: the keys and sizes of mesh-fxxxxx_smplx.pkl
            fit = {"global_orient": np.array(p["root_pose"]), "body_pose": np.array(p["body_pose"]).reshape(63),
                   "left_hand_pose": np.array(p["lhand_pose"]).reshape(45),
                   "right_hand_pose": np.array(p["rhand_pose"]).reshape(45), "jaw_pose": np.array(p["jaw_pose"]),
                   "leye_pose": np.array(p["leye_pose"]), "reye_pose": np.array(p["reye_pose"]),
                   "transl": np.array(p["trans"]), "betas": mean_shape.copy(), "expression": np.zeros(10)}
            (d / "SMPLX").mkdir(parents=True, exist_ok=True)
            with open(d / "SMPLX" / f"mesh-f{idx:05d}_smplx.pkl", "wb") as f:
                pickle.dump(fit, f)
            frame = {"name": f"{take}_{idx:06d}", "split": split, "R": R, "t": t, "focal": FOCAL, "princpt": PRINCPT}
            xhumans.frames.append({**frame, "params": p, "in_camera": False})
            if take in exavatar_takes:  # ExAvatar's refit: its own body and poses, the same pelvis, camera frame
                q = _fit(rng, root_world, pelvis, R, t, j0_ex, in_camera=True)
                _json(d / "smplx_optimized" / "smplx_params" / f"{idx}.json", q)
                exavatar.frames.append({**frame, "params": q, "in_camera": True})
        np.savez(d / "render" / "cameras.npz", intrinsic=intr, extrinsic=np.stack(extr))
    scenes = {"xhumans": xhumans, "exavatar": exavatar}
    for scene in scenes.values():
        scene.by_source = scenes
    return exavatar if set(exavatar_takes) >= {"Take1", "Take2", "Take9"} else xhumans


def write_smplerx(root: Path, model_dir: Path, seed: int = 3) -> Scene:
    """SMPLer-X's demo output for 5 frames (the 5th is test), laid out as caizhongang/SMPLer-X main/inference.py
    writes it: frames read as ``{frame:06d}.jpg`` from frame 1 (its --start default), fits
    ``smplx/{frame:05}_{bbox_id}.npz`` (global_orient [1, 3], body_pose [21, 3], hand poses [15, 3], jaw_pose,
    leye_pose and reye_pose (zeros) [1, 3], betas [1, 10], expression [1, 10], transl = cam_trans [1, 3]: smplx's
    transl, its mesh being the layer's vertices + cam_trans) and ``meta/{frame:05}_{bbox_id}.json`` with a
    per-frame focal and princpt (its crop's camera in full-image pixels). Frames 2 and 4 hold a second person
    (bbox_id 1). Camera at the origin; the person stands along about -y."""
    rng = np.random.default_rng(seed)
    betas = rng.normal(scale=0.5, size=10)
    scene = Scene(betas=betas, gender="neutral", up=axis_angle_to_matrix(np.array([0.15, 0.0, 0.0])) @ -E_Y)
    j0 = _pelvis(model_dir, scene)
    for frame in range(1, 6):
        img, mask = _image_and_mask(rng)
        _png(root / "frames" / f"{frame:06d}.jpg", img)
        _png(root / "masks" / f"{frame:06d}.png", mask)
        focal = (FOCAL[0] * (1 + 0.1 * frame), FOCAL[1] * (1 + 0.1 * frame))
        princpt = (PRINCPT[0] + frame, PRINCPT[1] - frame)
        for person in (0, 1) if frame in (2, 4) else (0,):
            pelvis = np.array([0.0, 0.0, DISTANCE]) if person == 0 else np.array([1.0, 0.2, 4.0])
            p = _fit(rng, _standing_root(rng, scene.up), pelvis, np.eye(3), np.zeros(3), j0, in_camera=True)
            p = {**p, "leye_pose": [0.0] * 3, "reye_pose": [0.0] * 3}
            (root / "fits" / "smplx").mkdir(parents=True, exist_ok=True)
            np.savez(root / "fits" / "smplx" / f"{frame:05}_{person}.npz", global_orient=np.array(p["root_pose"])[None],
                     body_pose=np.array(p["body_pose"]), left_hand_pose=np.array(p["lhand_pose"]),
                     right_hand_pose=np.array(p["rhand_pose"]), jaw_pose=np.array(p["jaw_pose"])[None],
                     leye_pose=np.zeros((1, 3)), reye_pose=np.zeros((1, 3)), betas=betas[None],
                     expression=rng.normal(size=(1, 10)), transl=np.array(p["trans"])[None])
            _json(root / "fits" / "meta" / f"{frame:05}_{person}.json",
                  {"focal": list(focal), "princpt": list(princpt), "bbox": [0.0, 0.0, 64.0, 64.0],
                   "bbox_mmdet": [1.0, 1.0, 60.0, 62.0], "bbox_id": person, "img_path": f"{frame:06d}.jpg"})
            if person == 0:
                scene.frames.append({"name": f"{frame:06d}", "split": "test" if frame == 5 else "train", "params": p,
                                     "R": np.eye(3), "t": np.zeros(3), "in_camera": True, "focal": focal,
                                     "princpt": princpt})
    return scene
