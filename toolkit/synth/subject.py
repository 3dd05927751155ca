"""Synthetic subjects: a seeded body, clothing texture, training and test motions, cameras, frames.

Training frames mimic a monocular capture: a fixed camera and a subject turning in place through
360 degrees (or ``coverage`` of a turn: a capture seen from one side) with mild arm and leg motion.
Test frames are novel poses (arms raised, squat, step,
wave) seen from novel views (other elevations, distances and body orientations). Frames are
rendered by the z-buffer mesh rasterizer with per-pixel texture lookup and 2x2 supersampling.
"""

from __future__ import annotations

import dataclasses
import itertools
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from trioman import __version__
from trioman.runtime import motions
from trioman.runtime.cameras import intrinsics, orbit_viewmat
from trioman.runtime.formats import Subject, save_subject
from trioman.runtime.image_io import write_png
from trioman.runtime.preview import contact_sheet
from trioman.runtime.rotations import axis_angle_to_matrix, matrix_to_axis_angle
from trioman.runtime.skeleton import SkinnedMesh
from trioman.toolkit.body.anny_model import PHENOTYPE_LABELS
from trioman.toolkit.body.registry import create_body_model
from trioman.toolkit.synth.shading import render_textured
from trioman.toolkit.synth.texture import bake_texture

# Novel views for the test motions: (azimuth deg, elevation deg, distance m, body yaw rad).
TEST_VIEWS = {
    "arms_raised": (30.0, 25.0, 3.3, 0.5),
    "squat": (-60.0, -10.0, 2.9, -2.2),
    "step": (100.0, 18.0, 3.2, 2.7),
    "wave": (-25.0, 35.0, 3.4, -0.7),
}
TRAIN_VIEW = (0.0, 5.0, 3.0)  # azimuth deg, elevation deg, distance m


@dataclass(frozen=True)
class SynthConfig:
    seed: int = 0
    size: int = 256  # square image side in pixels
    frames: int = 120  # total frames: training turn + test motions
    test_fraction: float = 0.2
    pose_noise_deg: float = 0.0  # std of the noise added to the stored (fitted) poses
    fill: float = 0.75  # fraction of the image height the rest body spans from the training camera
    texture_size: int = 1024
    supersample: int = 2
    body_model: str = "anny"
    coverage: float = 1.0  # fraction of a full turn the training frames span, from facing the camera (1: all round)

    def __post_init__(self) -> None:
        if self.size < 16:
            raise ValueError(f"size: must be >= 16 pixels, got {self.size}")
        if self.frames < 2 + len(TEST_VIEWS):
            raise ValueError(f"frames: need at least {2 + len(TEST_VIEWS)} (training + one per test motion), got {self.frames}")
        if not 0.0 < self.test_fraction < 1.0:
            raise ValueError(f"test_fraction: must lie in (0, 1), got {self.test_fraction}")
        if not (0.0 <= self.pose_noise_deg <= 90.0):
            raise ValueError(f"pose_noise_deg: must lie in [0, 90] degrees, got {self.pose_noise_deg}")
        if not 0.1 <= self.fill <= 0.95:
            raise ValueError(f"fill: must lie in [0.1, 0.95], got {self.fill}")
        if not (isinstance(self.coverage, (int, float)) and 0.0 < self.coverage <= 1.0):
            raise ValueError(f"coverage: must lie in (0, 1] (fraction of a full turn), got {self.coverage!r}")
        if self.supersample < 1 or self.texture_size < 64:
            raise ValueError(f"supersample/texture_size: got {self.supersample}/{self.texture_size}")

    @property
    def num_test(self) -> int:
        return max(len(TEST_VIEWS), int(round(self.frames * self.test_fraction)))


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
    parts = [motions.turn_in_place(sk, n_train, turns=cfg.coverage)]
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


def framing_intrinsics(mesh: SkinnedMesh, cfg: SynthConfig) -> np.ndarray:
    """Square-pixel K whose focal makes the rest body span ``cfg.fill`` of the image from the training camera."""
    height = float(np.ptp(mesh.vertices[:, 2]))
    f = cfg.fill * cfg.size * TRAIN_VIEW[2] / height
    return intrinsics(f, f, cfg.size / 2, cfg.size / 2)


def build_body(cfg: SynthConfig) -> tuple[SkinnedMesh, dict[str, float]]:
    phenotype = phenotype_from_seed(cfg.seed)
    with torch.no_grad():
        body = create_body_model(cfg.body_model, phenotype=phenotype, dtype=torch.float64)
    return body.to_skinned_mesh(), phenotype


def synthesize_subject(cfg: SynthConfig, out: str | Path, overwrite: bool = False, progress: bool = True) -> Subject:
    """Render a synthetic subject into ``out`` (subject format, docs/formats.md) with a contact sheet."""
    mesh, phenotype = build_body(cfg)
    texture = bake_texture(mesh, seed=cfg.seed, size=cfg.texture_size)
    seq = plan_sequences(mesh, cfg)
    stored = perturb_poses(seq.pose, cfg.pose_noise_deg, np.random.default_rng([cfg.seed, 2]))

    def frames():
        for i in tqdm(range(cfg.frames), desc="synth: rendering", unit="frame", disable=None if progress else True):
            verts = mesh.pose(seq.pose[i], seq.trans[i])
            yield render_textured(mesh, verts, texture, seq.viewmat[i], seq.K[i], cfg.size, cfg.size, cfg.supersample)

    # One render pass feeds both iterables; tee holds only what one side has read ahead.
    for_images, for_masks = itertools.tee(frames())
    subject = save_subject(
        out,
        body=mesh,
        poses=stored.astype(np.float32),
        trans=seq.trans.astype(np.float32),
        K=seq.K.astype(np.float32),
        viewmat=seq.viewmat.astype(np.float32),
        split=seq.split,
        sequence=seq.sequence,
        images=(rgb for rgb, _ in for_images),
        masks=(mask for _, mask in for_masks),
        width=cfg.size,
        height=cfg.size,
        body_model=cfg.body_model,
        phenotype=phenotype,
        generator={"tool": "trioman synth", "version": __version__, **dataclasses.asdict(cfg)},
        poses_true=seq.pose.astype(np.float32),
        overwrite=overwrite,
    )
    write_png(Path(out) / "contact_sheet.png", subject_contact_sheet(subject))
    return subject


def subject_contact_sheet(subject: Subject, train: int = 8, per_test: int = 1) -> np.ndarray:
    """Sampled training frames and the middle of each test sequence, captioned."""
    picks = list(subject.indices("train")[np.linspace(0, len(subject.indices("train")) - 1, train).astype(int)])
    for name in subject.sequences:
        idx = subject.indices(sequence=name)
        if name.startswith("test"):
            picks += list(idx[np.linspace(len(idx) // 2, len(idx) - 1, per_test).astype(int)])
    labels = [f"{subject.frame_names[i]} {subject.sequence[i].replace('test_', '')}" for i in picks]
    return contact_sheet([subject.image(i) for i in picks], labels, cols=6)


class TruthRenderer:
    """A synthetic subject's own mesh renderer, rebuilt from its subject.json: the truth at any pose and camera
    (the ceiling of augmentation: what a perfect Refiner would return at a Generator draw)."""

    def __init__(self, subject: Subject) -> None:
        made = dict(subject.meta.get("generator", {}))
        if made.pop("tool", None) != "trioman synth":
            raise ValueError(f"{subject.root}: not a synthetic subject (subject.json generator.tool is not 'trioman synth'); "
                             "the truth exists only for `trioman synth` subjects")
        made.pop("version", None)
        self.cfg = SynthConfig(**made)
        self.mesh, _ = build_body(self.cfg)
        self.texture = bake_texture(self.mesh, seed=self.cfg.seed, size=self.cfg.texture_size)
        self.poses_true = subject.poses if subject.poses_true is None else subject.poses_true
        self.poses, self.width, self.height = subject.poses, subject.width, subject.height

    def render(self, pose: np.ndarray, trans: np.ndarray, viewmat: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """-> (rgb [H, W, 3] on black, mask [H, W]) of the body at ``pose`` [J, 3], ``trans`` [3]."""
        verts = self.mesh.pose(np.asarray(pose, np.float64), np.asarray(trans, np.float64))
        return render_textured(self.mesh, verts, self.texture, viewmat, np.asarray(K, np.float64), self.width, self.height,
                               self.cfg.supersample)

    def at_draw(self, index: int, candidate, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The truth at a Generator candidate of frame ``index``: the candidate's pose change applied to the frame's
        true pose (the stored pose may carry fitting noise), its camera."""
        pose = np.asarray(self.poses_true[index], np.float64) + np.asarray(candidate.delta_pose, np.float64)
        return self.render(pose, candidate.trans, candidate.viewmat, K)
