"""Procedural motions for a named skeleton (Anny joint names), in numpy.

A motion is per-frame axis-angle poses [T, J, 3] and root translations [T, 3] in the convention
of trioman.runtime.skeleton (world-aligned axes; z up; the subject faces -y, its left is +x), with
the joint names it was made for and a frame rate. ``MOTIONS`` are the shipped procedural motions
(walk, wave, squat, turn, jump, step, arms_raised), each a function (skeleton, frames) -> Motion;
``Motion.for_skeleton`` maps a motion onto another skeleton's joint order by name.
Rotation signs on this skeleton: about +y lowers the left arm and raises the right; about -x
swings a leg or arm forward; about +x bends a knee.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from trioman.runtime.skeleton import Skeleton


DEFAULT_FPS = 30.0


@dataclass(frozen=True, eq=False)
class Motion:
    name: str
    pose: np.ndarray  # [T, J, 3] axis-angle
    trans: np.ndarray  # [T, 3]
    joint_names: tuple[str, ...] | None = None  # [J] the joints of ``pose``; None: the skeleton's order
    fps: float = DEFAULT_FPS

    @property
    def num_frames(self) -> int:
        return len(self.pose)

    def for_skeleton(self, skeleton: Skeleton) -> "Motion":
        """This motion in ``skeleton``'s joint order: joints matched by name, joints the motion does not
        name keep their rest rotation. A joint the skeleton lacks is an error naming it."""
        names = self.joint_names
        if names is None or tuple(names) == skeleton.joint_names:
            if self.pose.shape[1] != skeleton.num_joints:
                raise ValueError(f"pose: motion {self.name!r} has {self.pose.shape[1]} joints, the skeleton "
                                 f"{skeleton.num_joints} (and the motion names none)")
            return Motion(self.name, self.pose, self.trans, skeleton.joint_names, self.fps)
        unknown = [n for n in names if n not in skeleton.joint_names]
        if unknown:
            shown = ", ".join(repr(n) for n in unknown[:5]) + (" ..." if len(unknown) > 5 else "")
            raise ValueError(f"joint_names: {len(unknown)} joint(s) of motion {self.name!r} are not in the "
                             f"avatar's skeleton ({skeleton.num_joints} joints): {shown}")
        pose = np.zeros((self.num_frames, skeleton.num_joints, 3), dtype=self.pose.dtype)
        pose[:, [skeleton.index(n) for n in names]] = self.pose
        return Motion(self.name, pose, self.trans, skeleton.joint_names, self.fps)


def _phase(frames: int) -> np.ndarray:
    """[T] in [0, 1)."""
    if frames < 1:
        raise ValueError(f"frames: must be >= 1, got {frames}")
    return np.arange(frames) / frames


def _smoothstep(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3 - 2 * x)


class _Builder:
    """Accumulates per-joint rotations by name."""

    def __init__(self, skeleton: Skeleton, frames: int):
        self.skeleton = skeleton
        self.pose = np.zeros((frames, skeleton.num_joints, 3))
        self.trans = np.zeros((frames, 3))

    def rot(self, joint: str, axis: int, angle: np.ndarray | float) -> "_Builder":
        self.pose[:, self.skeleton.index(joint), axis] += angle
        return self

    def sym(self, stem: str, axis: int, left: np.ndarray | float, right: np.ndarray | float) -> "_Builder":
        return self.rot(f"{stem}.L", axis, left).rot(f"{stem}.R", axis, right)

    def grounded(self, name: str) -> Motion:
        """Lift or lower each frame so the lowest foot joint stays at its rest height."""
        feet = [self.skeleton.index(n) for n in self.skeleton.joint_names if n.startswith(("foot.", "toe"))]
        G = self.skeleton.forward_kinematics(self.pose, self.trans)
        rest_low = self.skeleton.joints[feet, 2].min()
        self.trans[:, 2] += rest_low - G[:, feet, 2, 3].min(axis=1)
        return Motion(name, self.pose, self.trans, self.skeleton.joint_names)


def turn_in_place(skeleton: Skeleton, frames: int, turns: float = 1.0) -> Motion:
    """Training motion of a monocular capture: ``turns`` turns about z with mild arm and leg motion."""
    t = _phase(frames)
    w = 2 * np.pi * t
    b = _Builder(skeleton, frames).rot("root", 2, turns * w)
    b.sym("upperarm01", 0, 0.25 * np.sin(3 * w), -0.25 * np.sin(3 * w))
    b.sym("upperarm01", 1, -0.12 * (1 - np.cos(2 * w)), 0.12 * (1 - np.cos(2 * w)))
    b.sym("lowerarm01", 0, -0.2 * (1 + np.sin(5 * w)), -0.2 * (1 - np.sin(5 * w)))
    b.sym("upperleg01", 0, 0.12 * np.sin(6 * w), -0.12 * np.sin(6 * w))
    b.sym("lowerleg01", 0, 0.1 * (1 + np.sin(6 * w)), 0.1 * (1 - np.sin(6 * w)))
    b.rot("head", 2, 0.15 * np.sin(2 * w))
    return b.grounded("train_turn")


def arms_raised(skeleton: Skeleton, frames: int) -> Motion:
    """Both arms lifted from the sides to above the head (beyond the training range)."""
    e = 0.35 + 0.65 * _smoothstep(1.6 * _phase(frames))
    b = _Builder(skeleton, frames)
    b.sym("upperarm01", 1, -2.3 * e, 2.3 * e)
    b.sym("lowerarm01", 1, -0.3 * e, 0.3 * e)
    b.rot("spine01", 0, 0.1 * e)
    return b.grounded("test_arms_raised")


def squat(skeleton: Skeleton, frames: int) -> Motion:
    """A squat: hips and knees bend, arms forward for balance."""
    e = 0.3 + 0.7 * np.sin(np.pi * _phase(frames) * 0.999) ** 2
    b = _Builder(skeleton, frames)
    b.sym("upperleg01", 0, -1.25 * e, -1.25 * e)
    b.sym("upperleg01", 1, 0.15 * e, -0.15 * e)
    b.sym("lowerleg01", 0, 2.0 * e, 2.0 * e)
    b.sym("foot", 0, -0.75 * e, -0.75 * e)
    b.rot("spine04", 0, -0.35 * e)
    b.sym("upperarm01", 0, -0.9 * e, -0.9 * e)
    b.sym("upperarm01", 1, -0.3 * e, 0.3 * e)
    return b.grounded("test_squat")


def step(skeleton: Skeleton, frames: int) -> Motion:
    """A long step forward with the left leg, arms swinging in opposition."""
    e = 0.3 + 0.7 * _smoothstep(1.5 * _phase(frames))
    b = _Builder(skeleton, frames)
    b.rot("upperleg01.L", 0, -0.75 * e).rot("lowerleg01.L", 0, 0.45 * e).rot("foot.L", 0, 0.2 * e)
    b.rot("upperleg01.R", 0, 0.45 * e).rot("lowerleg01.R", 0, 0.25 * e).rot("foot.R", 0, -0.25 * e)
    b.rot("upperarm01.L", 0, 0.55 * e).rot("upperarm01.R", 0, -0.7 * e)
    b.rot("lowerarm01.R", 0, -0.6 * e)
    b.trans[:, 1] -= 0.25 * e
    return b.grounded("test_step")


def wave(skeleton: Skeleton, frames: int) -> Motion:
    """The right arm raised with the forearm waving; head turned to the side."""
    t = _phase(frames)
    e = 0.4 + 0.6 * _smoothstep(3 * t)
    b = _Builder(skeleton, frames)
    b.rot("upperarm01.R", 1, 2.0 * e).rot("upperarm01.R", 0, -0.3 * e)
    b.rot("lowerarm01.R", 1, 0.9 * e + 0.55 * np.sin(2 * np.pi * 3 * t))
    b.rot("upperarm01.L", 0, 0.2 * e)
    b.rot("head", 2, -0.45 * e).rot("neck01", 0, 0.15 * e)
    return b.grounded("test_wave")


def walk(skeleton: Skeleton, frames: int, cycles: float = 2.0, speed: float = 1.1) -> Motion:
    """Walking forward (towards -y, the way the subject faces) at ``speed`` m/s and 30 fps, arms
    swinging in opposition; ``cycles`` strides of both legs over the clip."""
    t = _phase(frames)
    w = 2 * np.pi * cycles * t
    b = _Builder(skeleton, frames)
    b.sym("upperleg01", 0, -0.45 * np.sin(w), 0.45 * np.sin(w))
    # the knee bends while its leg swings forward (the hip angle's rate is cos w)
    b.sym("lowerleg01", 0, 0.05 + 0.7 * np.maximum(np.cos(w), 0) ** 2, 0.05 + 0.7 * np.maximum(-np.cos(w), 0) ** 2)
    b.sym("foot", 0, -0.15 * np.sin(w), 0.15 * np.sin(w))
    b.sym("upperarm01", 1, 0.35, -0.35)  # arms down by the sides
    b.sym("upperarm01", 0, 0.4 * np.sin(w), -0.4 * np.sin(w))
    b.sym("lowerarm01", 0, -0.25 - 0.15 * np.sin(w), -0.25 + 0.15 * np.sin(w))
    b.rot("spine01", 2, 0.08 * np.sin(w))
    b.trans[:, 1] = -speed * np.arange(frames) / DEFAULT_FPS
    return b.grounded("walk")


def jump(skeleton: Skeleton, frames: int, height: float = 0.35) -> Motion:
    """A standing jump: crouch, take off with the arms swinging up, fly ``height`` m, land and recover."""
    t = _phase(frames)
    crouch = np.sin(np.pi * np.clip(t / 0.3, 0, 1)) ** 2 + np.sin(np.pi * np.clip((t - 0.7) / 0.3, 0, 1)) ** 2
    air = np.clip((t - 0.3) / 0.4, 0, 1)
    b = _Builder(skeleton, frames)
    b.sym("upperleg01", 0, -0.9 * crouch, -0.9 * crouch)
    b.sym("lowerleg01", 0, 1.4 * crouch + 0.3 * np.sin(np.pi * air), 1.4 * crouch + 0.3 * np.sin(np.pi * air))
    b.sym("foot", 0, -0.5 * crouch + 0.4 * np.sin(np.pi * air), -0.5 * crouch + 0.4 * np.sin(np.pi * air))
    b.rot("spine04", 0, -0.3 * crouch)
    swing = np.where(t < 0.3, 0.6 * crouch, -1.8 * np.sin(np.pi * air) + 0.6 * crouch)
    b.sym("upperarm01", 0, swing, swing)
    b.sym("upperarm01", 1, 0.3, -0.3)
    m = b.grounded("jump")
    m.trans[:, 2] += 4 * height * air * (1 - air)  # the flight, after grounding
    return m


def turn(skeleton: Skeleton, frames: int) -> Motion:
    """One full turn in place (the synthetic subjects' training motion)."""
    m = turn_in_place(skeleton, frames)
    return Motion("turn", m.pose, m.trans, m.joint_names, m.fps)


TEST_MOTIONS: dict[str, Callable[[Skeleton, int], Motion]] = {
    "arms_raised": arms_raised,
    "squat": squat,
    "step": step,
    "wave": wave,
}

# The shipped procedural motions, by name (``trioman animate --motion NAME``), with default lengths.
MOTIONS: dict[str, Callable[[Skeleton, int], Motion]] = {
    "walk": walk,
    "wave": wave,
    "squat": squat,
    "turn": turn,
    "jump": jump,
    "step": step,
    "arms_raised": arms_raised,
}
DEFAULT_FRAMES = {"walk": 60, "wave": 60, "squat": 60, "turn": 90, "jump": 45, "step": 45, "arms_raised": 45}
