"""Synthetic subjects: a seeded body, clothing texture, training and test motions, cameras, frames.

Training frames mimic a monocular capture: a fixed camera and a subject turning in place through
360 degrees (or ``coverage`` of a turn: a capture seen from one side) with mild arm and leg motion
(``capture="steps"``: a few steps across the view first).
Test frames are novel poses (arms raised, squat, step,
wave) seen from novel views (other elevations, distances and body orientations). Frames are
rendered by the z-buffer mesh rasterizer with per-pixel texture lookup and 2x2 supersampling.

Two styles: ``plain`` paints the clothes on a bald body on black (the unit tests' subjects); ``realistic``
dresses the body in hair, garments and shoes of their own geometry, lights it with a world-fixed key light
and soft shadows, puts it in a room and films it with a hand-held phone (``toolkit/synth/realistic.py``).
Either way the truth stays exact: the person mask (hair and garments included), the poses, the cameras,
and ``TruthRenderer`` re-renders the whole person at any pose and camera.
"""

from __future__ import annotations

import dataclasses
import itertools
import multiprocessing
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from trioman import __version__
from trioman.runtime import motions
from trioman.runtime.cameras import intrinsics, orbit_viewmat, project
from trioman.runtime.formats import Subject, save_subject
from trioman.runtime.image_io import VideoWriter, write_png
from trioman.runtime.preview import contact_sheet
from trioman.runtime.rotations import axis_angle_to_matrix, matrix_to_axis_angle
from trioman.runtime.skeleton import SkinnedMesh
from trioman.toolkit.body.anny_model import PHENOTYPE_LABELS
from trioman.toolkit.body.registry import create_body_model
from trioman.toolkit.synth.realistic import Scene, handheld
from trioman.toolkit.synth.shading import render_textured
from trioman.toolkit.synth.config import TEST_VIEWS, SynthConfig
from trioman.toolkit.synth.texture import bake_texture

TRAIN_VIEW = (0.0, 5.0, 3.0)  # azimuth deg, elevation deg, distance m
STEPS_REACH = 0.35  # m either side of the centre a "steps" capture walks
VIDEO_FPS = 30.0


def phenotype_from_seed(seed: int) -> dict[str, float]:
    """An adult body shape drawn from the seed."""
    rng = np.random.default_rng([seed, 1])
    ranges = {"gender": (0.0, 1.0), "age": (0.45, 0.75), "muscle": (0.25, 0.75), "weight": (0.25, 0.75),
              "height": (0.3, 0.8), "proportions": (0.3, 0.7)}
    return {k: round(float(rng.uniform(*ranges[k])), 4) for k in PHENOTYPE_LABELS}


def perturb_poses(pose: np.ndarray, deg: float, rng: np.random.Generator) -> np.ndarray:
    """Compose each joint rotation with a random rotation of ~``deg`` degrees (per-axis std). [N, J, 3]."""
    if deg == 0:
        return pose.copy()
    noise = axis_angle_to_matrix(rng.normal(scale=np.deg2rad(deg), size=pose.shape))
    return matrix_to_axis_angle(noise @ axis_angle_to_matrix(pose))


def _yawed(m: motions.Motion, yaw: float, root: np.ndarray) -> motions.Motion:
    """The motion with the whole body turned by ``yaw`` about the world z axis. root: [3] rest root joint."""
    Rz = axis_angle_to_matrix(np.array([0.0, 0.0, yaw]))
    pose = m.pose.copy()
    pose[:, 0] = matrix_to_axis_angle(Rz @ axis_angle_to_matrix(pose[:, 0]))
    # The root joint sits at root + trans; turn that point too.
    return motions.Motion(m.name, pose, (root + m.trans) @ Rz.T - root)


@dataclass(frozen=True, eq=False)
class Sequences:
    """Everything about the frames except the pixels."""

    pose: np.ndarray  # [N, J, 3] true poses
    trans: np.ndarray  # [N, 3]
    K: np.ndarray  # [N, 3, 3]
    viewmat: np.ndarray  # [N, 4, 4]
    split: list[str]
    sequence: list[str]


def plan_sequences(mesh: SkinnedMesh, cfg: SynthConfig) -> Sequences:
    """Motions and cameras for every frame of the subject."""
    sk = mesh.skeleton
    n_test = cfg.num_test
    n_train = cfg.frames - n_test
    center = np.array([0.0, 0.0, 0.5 * (mesh.vertices[:, 2].min() + mesh.vertices[:, 2].max())])
    K = framing_intrinsics(mesh, cfg)
    parts = [_capture(sk, n_train, cfg)]
    views = [orbit_viewmat(center, np.deg2rad(TRAIN_VIEW[0]), np.deg2rad(TRAIN_VIEW[1]), TRAIN_VIEW[2])]
    counts = np.full(len(TEST_VIEWS), n_test // len(TEST_VIEWS))
    counts[: n_test % len(TEST_VIEWS)] += 1
    for (name, (az, el, dist, yaw)), count in zip(TEST_VIEWS.items(), counts):
        parts.append(_yawed(motions.TEST_MOTIONS[name](sk, int(count)), yaw, sk.joints[0]))
        views.append(orbit_viewmat(center, np.deg2rad(az), np.deg2rad(el), dist))
    viewmat = np.concatenate([np.repeat(v[None], p.num_frames, 0) for v, p in zip(views, parts)])
    return Sequences(
        pose=np.concatenate([p.pose for p in parts]),
        trans=np.concatenate([p.trans for p in parts]),
        K=np.repeat(K[None], cfg.frames, 0),
        viewmat=viewmat,
        split=["train"] * n_train + ["test"] * n_test,
        sequence=sum(([p.name] * p.num_frames for p in parts), []),
    )


def _capture(sk, frames: int, cfg: SynthConfig) -> motions.Motion:
    """The training motion: the turn (``coverage`` of a turn from facing the camera), after a few steps towards
    the camera for "steps"."""
    if cfg.capture == "turn":
        return motions.turn_in_place(sk, frames, turns=cfg.coverage)
    n_walk = max(2, frames // 3)
    walk = motions.walk(sk, n_walk, cycles=1.0, speed=2 * STEPS_REACH * motions.DEFAULT_FPS / n_walk)
    walk_trans = walk.trans + np.array([0.0, STEPS_REACH, 0.0])  # from behind the centre to in front of it
    turn = motions.turn_in_place(sk, frames - n_walk, turns=cfg.coverage)
    turn_trans = turn.trans + np.array([walk_trans[-1, 0], walk_trans[-1, 1], 0.0])
    return motions.Motion("train_turn", np.concatenate([walk.pose, turn.pose]), np.concatenate([walk_trans, turn_trans]))


def framing_intrinsics(mesh: SkinnedMesh, cfg: SynthConfig) -> np.ndarray:
    """Square-pixel K whose focal makes the rest body span ``cfg.fill`` of the image height from the training camera
    (of its width when that is the tighter side: a portrait frame and the rest pose's outstretched arms)."""
    height = float(np.ptp(mesh.vertices[:, 2]))
    width = float(np.ptp(mesh.vertices[:, 0]))
    f = cfg.fill * min(cfg.height / height, cfg.width / width) * TRAIN_VIEW[2]
    return intrinsics(f, f, cfg.width / 2, cfg.height / 2)


def build_body(cfg: SynthConfig) -> tuple[SkinnedMesh, dict[str, float]]:
    phenotype = phenotype_from_seed(cfg.seed)
    with torch.no_grad():
        body = create_body_model(cfg.body_model, phenotype=phenotype, dtype=torch.float64)
    return body.to_skinned_mesh(), phenotype


class SubjectRenderer:
    """A synthetic subject's image formation, from its config alone: the truth of the person at any pose and
    camera (``person``) and what the camera recorded at each frame (``recorded``)."""

    def __init__(self, cfg: SynthConfig, mesh: SkinnedMesh) -> None:
        self.cfg, self.body = cfg, mesh
        if cfg.style == "plain":
            self.texture = bake_texture(mesh, seed=cfg.seed, size=cfg.texture_size)
            self.scene = None
        else:
            self.scene = Scene(mesh, cfg.seed, cfg.scene_outfit(), cfg.texture_size)

    def cameras(self, viewmat: np.ndarray) -> np.ndarray:
        """The frames' cameras [N, 4, 4]: the planned ones turned by the phone's hand-held jitter (realistic)."""
        if self.scene is None:
            return viewmat
        R = handheld(len(viewmat), self.cfg.handheld_deg, self.cfg.seed)  # [N, 3, 3] in the camera frame
        out = viewmat.copy()
        out[:, :3, :] = np.einsum("nab,nbc->nac", R, viewmat[:, :3, :])
        return out

    def person(self, pose: np.ndarray, trans: np.ndarray, viewmat: np.ndarray, K: np.ndarray, width: int,
               height: int) -> tuple[np.ndarray, np.ndarray]:
        """The whole person (garments and hair included) at ``pose`` [J, 3], ``trans`` [3], sharp and clean
        -> (rgb [H, W, 3] premultiplied on black, coverage mask [H, W])."""
        pose, trans, K = np.asarray(pose, np.float64), np.asarray(trans, np.float64), np.asarray(K, np.float64)
        if self.scene is None:
            verts = self.body.pose(pose, trans)
            return render_textured(self.body, verts, self.texture, viewmat, K, width, height, self.cfg.supersample)
        return self.scene.person(self.scene.mesh.pose(pose, trans), viewmat, K, width, height, self.cfg.supersample)

    def recorded(self, i: int, seq: Sequences, viewmat: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Frame ``i`` as the camera recorded it -> (frame [H, W, 3] with its background, the subject's image
        (frame x mask, premultiplied on black) [H, W, 3], the true person mask [H, W])."""
        W, H = self.cfg.width, self.cfg.height
        if self.scene is None:
            rgb, mask = self.person(seq.pose[i], seq.trans[i], viewmat[i], seq.K[i], W, H)
            return rgb, rgb, mask
        samples = _shutter(self.scene.mesh, seq, viewmat, i, self.scene.sensor.shutter_samples)
        frame, mask = self.scene.frame(samples, viewmat[i], seq.K[i], W, H, i, len(seq.pose), self.cfg.supersample)
        return frame, frame * mask[..., None], mask


BLUR_PX = 1.5  # the most any vertex may travel during the shutter, in pixels (slight motion blur)


def _shutter(mesh: SkinnedMesh, seq: Sequences, viewmat: np.ndarray, i: int, samples: int) -> list[np.ndarray]:
    """Posed vertices across the shutter of frame ``i``: ``samples`` instants between its poses and its sequence's
    neighbours', open for a quarter of a frame interval either side or until a vertex travels ``BLUR_PX`` (a joint
    that jumps by more than 0.5 rad, an axis-angle wrapping round, holds the frame's own rotation). -> [samples] [V, 3]"""
    here = mesh.pose(seq.pose[i], seq.trans[i])
    if samples <= 1:
        return [here]
    xy, _ = project(here, viewmat[i], seq.K[i])
    out = []
    for side in (-1, 1):
        j = i + side
        if not 0 <= j < len(seq.pose) or seq.sequence[j] != seq.sequence[i]:
            out += [here] * (samples // 2)
            continue
        dp = seq.pose[j] - seq.pose[i]
        dp *= (np.linalg.norm(dp, axis=-1) < 0.5)[:, None]
        there = mesh.pose(seq.pose[i] + dp, seq.trans[j])
        travel = float(np.max(np.linalg.norm(project(there, viewmat[i], seq.K[i])[0] - xy, axis=1)))
        reach = min(0.25, BLUR_PX / max(travel, 1e-9))
        for t in np.linspace(0, reach, samples // 2 + 1)[1:]:
            out.append(mesh.pose(seq.pose[i] + t * dp, seq.trans[i] + t * (seq.trans[j] - seq.trans[i])))
    return out


def _sheet_picks(split: list[str], sequence: list[str], train: int = 8, per_test: int = 1) -> list[int]:
    """Frames a contact sheet shows: ``train`` spread over the training frames, the middle of each test sequence."""
    split_a, seq_a = np.asarray(split), np.asarray(sequence)
    tr = np.flatnonzero(split_a == "train")
    picks = [int(k) for k in tr[np.linspace(0, len(tr) - 1, train).astype(int)]]
    for name in dict.fromkeys(sequence):
        idx = np.flatnonzero(seq_a == name)
        if name.startswith("test"):
            picks += [int(k) for k in idx[np.linspace(len(idx) // 2, len(idx) - 1, per_test).astype(int)]]
    return picks


_WORKER: tuple | None = None  # (renderer, seq, viewmat) of a forked rendering process


def _render_in_worker(i: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    renderer, seq, viewmat = _WORKER
    return renderer.recorded(i, seq, viewmat)


def _in_workers(renderer: SubjectRenderer, seq: Sequences, viewmat: np.ndarray, workers: int):
    """Frames in order, rendered by ``workers`` forked processes (each frame depends on its index alone, so the
    bytes are those of one process)."""
    global _WORKER
    _WORKER = (renderer, seq, viewmat)
    try:
        with multiprocessing.get_context("fork").Pool(workers) as pool:
            yield from pool.imap(_render_in_worker, range(len(seq.pose)), chunksize=2)
    finally:
        _WORKER = None


def synthesize_subject(cfg: SynthConfig, out: str | Path, overwrite: bool = False, progress: bool = True,
                       video: str | Path | None = None, workers: int | None = None,
                       video_frames: str = "train") -> Subject:
    """Render a synthetic subject into ``out`` (subject format, docs/formats.md) with a contact sheet; ``video``:
    the training frames (``video_frames`` "train"; "all": every frame, the test sequences after them) also as the
    MP4 a phone would have recorded (background, sensor and all), frame k of the video being the subject's frame
    k. The realistic style renders in ``workers`` processes (default: the CPUs this process may use, at most 4);
    the bytes do not depend on it."""
    if video_frames not in ("train", "all"):
        raise ValueError(f"video_frames: 'train' or 'all', got {video_frames!r}")
    workers = min(4, len(os.sched_getaffinity(0))) if workers is None else int(workers)
    if workers < 1:
        raise ValueError(f"workers: must be >= 1, got {workers}")
    if video is not None and Path(out).resolve() in (Path(video).resolve(), *Path(video).resolve().parents):
        raise ValueError(f"video: {video} lies inside the subject folder `out` ({out}); write it beside the subject")
    mesh, phenotype = build_body(cfg)
    renderer = SubjectRenderer(cfg, mesh)
    planned = plan_sequences(mesh, cfg)
    # Frames are rendered from the float32 values the subject stores, so TruthRenderer.recorded re-makes them exactly.
    f32 = lambda a: np.asarray(a, np.float32).astype(np.float64)  # noqa: E731
    seq = dataclasses.replace(planned, pose=f32(planned.pose), trans=f32(planned.trans), K=f32(planned.K))
    viewmat = f32(renderer.cameras(planned.viewmat))
    stored = perturb_poses(planned.pose, cfg.pose_noise_deg, np.random.default_rng([cfg.seed, 2]))
    picks = set(_sheet_picks(seq.split, seq.sequence))
    shown: dict[int, np.ndarray] = {}
    writer = VideoWriter(video, VIDEO_FPS) if video is not None else None

    def frames():
        made = _in_workers(renderer, seq, viewmat, workers) if cfg.style != "plain" and workers > 1 else \
            (renderer.recorded(i, seq, viewmat) for i in range(cfg.frames))
        for i, (frame, image, mask) in enumerate(tqdm(made, total=cfg.frames, desc="synth: rendering", unit="frame",
                                                       disable=None if progress else True)):
            if writer is not None and (video_frames == "all" or seq.split[i] == "train"):
                writer.write(frame)
            if i in picks and cfg.style != "plain":
                shown[i] = frame
            yield image, mask

    # One render pass feeds both iterables; tee holds only what one side has read ahead.
    for_images, for_masks = itertools.tee(frames())
    try:
        subject = save_subject(
            out,
            body=mesh,
            poses=stored.astype(np.float32),
            trans=seq.trans.astype(np.float32),
            K=seq.K.astype(np.float32),
            viewmat=viewmat.astype(np.float32),
            split=seq.split,
            sequence=seq.sequence,
            images=(rgb for rgb, _ in for_images),
            masks=(mask for _, mask in for_masks),
            width=cfg.width,
            height=cfg.height,
            body_model=cfg.body_model,
            phenotype=phenotype,
            generator={"tool": "trioman synth", "version": __version__, **dataclasses.asdict(cfg)},
            poses_true=seq.pose.astype(np.float32),
            overwrite=overwrite,
        )
    except BaseException:
        if writer is not None:
            writer.abort()
        raise
    if writer is not None:
        writer.close()
    write_png(Path(out) / "contact_sheet.png", subject_contact_sheet(subject, recorded=shown))
    return subject


def subject_contact_sheet(subject: Subject, recorded: dict[int, np.ndarray] | None = None) -> np.ndarray:
    """Sampled training frames and the middle of each test sequence, captioned; with ``recorded`` (frame index ->
    the camera's frame), each of those beside the subject's masked image."""
    picks = _sheet_picks(list(subject.split), list(subject.sequence))
    images, labels = [], []
    for i in picks:
        label = f"{subject.frame_names[i]} {subject.sequence[i].replace('test_', '')}"
        if recorded and i in recorded:
            images.append(recorded[i])
            labels.append(f"{label} video")
        images.append(subject.image(i))
        labels.append(label)
    return contact_sheet(images, labels, cols=6)


class TruthRenderer:
    """A synthetic subject's own renderer, rebuilt from its subject.json: the truth of the whole person (garments
    and hair included) at any pose and camera (the ceiling of augmentation: what a perfect Refiner would return
    at a Generator draw), and each stored frame exactly as it was recorded.

    A subject fitted from a synthetic subject's video and linked to it (``toolkit/synth/linked.py``) has its own
    world, poses and camera; its truth is the synthetic subject's renderer at the linked frames' true poses and
    cameras, a draw's pose change and camera move applied to them."""

    def __init__(self, subject: Subject) -> None:
        made = dict(subject.meta.get("generator", {}))
        link = made.get("truth")
        if link is None and made.get("tool") != "trioman synth":
            raise ValueError(f"{subject.root}: not a synthetic subject (subject.json generator.tool is not 'trioman synth' "
                             "and it holds no generator.truth link); the truth exists only for `trioman synth` subjects")
        if link is not None:
            self.trans_true, self.viewmat_true, self.K_true = _link_arrays(subject, link)
        synth = dict(made if link is None else link["synth"])
        synth.pop("tool", None)
        synth.pop("version", None)
        self.cfg = SynthConfig(**synth)
        self.mesh, _ = build_body(self.cfg)
        self.renderer = SubjectRenderer(self.cfg, self.mesh)
        self.subject, self.linked = subject, link is not None
        self.poses_true = subject.poses if subject.poses_true is None else subject.poses_true
        self.poses, self.width, self.height = subject.poses, subject.width, subject.height
        if not self.linked:
            self.trans_true, self.viewmat_true, self.K_true = subject.trans, subject.viewmat, subject.K

    def render(self, pose: np.ndarray, trans: np.ndarray, viewmat: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """-> (rgb [H, W, 3] on black, mask [H, W]) of the person at ``pose`` [J, 3], ``trans`` [3]."""
        return self.renderer.person(pose, trans, viewmat, K, self.width, self.height)

    def recorded(self, index: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Stored frame ``index`` re-made: (the camera's frame, the subject's image, its mask); equals the files."""
        if self.linked:
            raise ValueError(f"{self.subject.root}: a linked subject's frames come from its video; re-make them from the "
                             "synthetic subject it was fitted from")
        s = self.subject
        seq = Sequences(pose=np.asarray(self.poses_true, np.float64), trans=np.asarray(s.trans, np.float64),
                        K=np.asarray(s.K, np.float64), viewmat=np.asarray(s.viewmat, np.float64),
                        split=list(s.split), sequence=list(s.sequence))
        return self.renderer.recorded(index, seq, seq.viewmat)

    def at_draw(self, index: int, candidate, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The truth at a Generator candidate of frame ``index``: the candidate's pose change applied to the frame's
        true pose (the stored pose may carry fitting noise), its camera (``K`` [3, 3], the subject's own). A linked
        subject: the candidate's root shift (in its camera's axes) and its camera move (azimuth, elevation, distance
        about the frame's centre) applied to the truth's frame and camera, seen with the truth's intrinsics; the
        root's rotation change is added to the true root's as it is (the Generator's default leaves the root be)."""
        pose = np.asarray(self.poses_true[index], np.float64) + np.asarray(candidate.delta_pose, np.float64)
        if not self.linked:
            return self.render(pose, candidate.trans, candidate.viewmat, K)
        from trioman.runtime.generator import orbit_camera, subject_center

        seen, true_view = np.asarray(self.subject.viewmat[index], np.float64), np.asarray(self.viewmat_true[index], np.float64)
        shift = np.asarray(candidate.trans, np.float64) - np.asarray(self.subject.trans[index], np.float64)
        shift = true_view[:3, :3].T @ (seen[:3, :3] @ shift)  # the root's shift as its camera sees it
        trans = np.asarray(self.trans_true[index], np.float64)
        center = subject_center(self.mesh.skeleton, np.asarray(self.poses_true[index], np.float64), trans)
        d = candidate.camera
        viewmat = orbit_camera(true_view, center, d.azimuth, d.elevation, d.log_distance)
        return self.render(pose, trans + shift, viewmat, np.asarray(self.K_true[index], np.float64))


def _link_arrays(subject: Subject, link: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The truth's per-frame (trans [N, 3], viewmat [N, 4, 4], K [N, 3, 3]) of a linked subject, checked."""
    n = subject.num_frames
    if not isinstance(link, dict) or not isinstance(link.get("synth"), dict):
        raise ValueError(f"{subject.root}: subject.json generator.truth: expected an object with the synthetic subject's "
                         f"settings under 'synth', got {type(link).__name__}")
    out = []
    for key, shape in (("trans", (n, 3)), ("viewmat", (n, 4, 4)), ("K", (n, 3, 3))):
        try:
            a = np.asarray(link.get(key), np.float64)
        except (TypeError, ValueError):
            a = np.zeros((0,))
        if a.shape != shape or not np.isfinite(a).all():
            raise ValueError(f"{subject.root}: subject.json generator.truth.{key}: expected finite {list(shape)}, got shape {list(a.shape)}")
        out.append(a)
    if subject.poses_true is None:
        raise ValueError(f"{subject.root}: a linked subject stores the truth's poses as poses_true (frames.npz); none found")
    return out[0], out[1], out[2]
