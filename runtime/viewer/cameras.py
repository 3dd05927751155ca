"""A subject's training cameras in the viewer: frustums; a click shows the real frame beside the render.

The render is the numpy splat renderer's image of the avatar at that frame's stored pose, from that
frame's camera, over the subject's background, at most ``VIEW_SIDE`` pixels on its longer side (both
images resized alike), with the PSNR of the pair.
"""

from __future__ import annotations

import os

import cv2
import numpy as np

from trioman.runtime.cameras import camera_center
from trioman.runtime.formats import load_subject
from trioman.runtime.metrics import psnr
from trioman.runtime.motions import Motion
from trioman.runtime.render import rasterize
from trioman.runtime.rotations import matrix_to_quat

MAX_FRUSTUMS = 60  # more training cameras are thinned evenly
VIEW_SIDE = 256  # pixels, the longer side of each image of a pair
FRUSTUM_SCALE = 0.12  # metres
_COLOR = (40, 90, 200)


def frustum_pose(viewmat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World->camera [4, 4] (OpenCV, as viser's frustums) -> camera-to-world wxyz [4] and position [3]."""
    R = np.asarray(viewmat, dtype=np.float64)[:3, :3]
    return matrix_to_quat(R.T), camera_center(np.asarray(viewmat, dtype=np.float64))


class SubjectCameras:
    """The training cameras of ``subject_path`` on ``viewer`` (an ``AvatarViewer``)."""

    def __init__(self, viewer, subject_path: str | os.PathLike):
        self.viewer = viewer
        self.subject = s = load_subject(subject_path)
        avatar = viewer.poser.avatar
        frames = Motion("subject", np.array(s.poses), np.array(s.trans), s.body.skeleton.joint_names)
        self.frames = frames.for_skeleton(avatar.skeleton)  # joints matched by name
        train = s.indices("train")
        self.indices = train[np.unique(np.linspace(0, len(train) - 1, min(MAX_FRUSTUMS, len(train))).round().astype(int))] \
            if len(train) else train
        scene, gui = viewer.server.scene, viewer.server.gui
        for i in self.indices:
            wxyz, position = frustum_pose(s.viewmat[i])
            handle = scene.add_camera_frustum(
                f"/cameras/{s.frame_names[i]}", fov=float(2 * np.arctan(0.5 * s.height / s.K[i][1, 1])),
                aspect=s.width / s.height, scale=FRUSTUM_SCALE, color=_COLOR, wxyz=wxyz, position=position)
            handle.on_click(lambda _event, i=int(i): self.show(i))
        with gui.add_folder("Subject cameras"):
            self._caption = gui.add_markdown(f"{len(self.indices)} of {len(train)} training cameras of "
                                             f"{s.root.name}; click a frustum")
            self._image = gui.add_image(np.ones((8, 16, 3), np.uint8), label="real | avatar")

    def pair(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """Frame ``i``: the real image and the avatar's render from its camera, [h, w, 3] float32 each."""
        s, avatar = self.subject, self.viewer.poser.avatar
        scale = min(1.0, VIEW_SIDE / max(s.width, s.height))
        w, h = max(1, round(s.width * scale)), max(1, round(s.height * scale))
        K = np.array(s.K[i], dtype=np.float64)
        K[:2] *= np.array([[w / s.width], [h / s.height]])
        g = avatar.gaussians(self.frames.pose[i], self.frames.trans[i], pose_dependent=self.viewer.controls.pose_dependent)
        render = rasterize(*g, np.array(s.viewmat[i], dtype=np.float64), K, w, h, background=s.background).rgb
        real = cv2.resize(s.image(i), (w, h), interpolation=cv2.INTER_AREA) if (w, h) != (s.width, s.height) else s.image(i)
        return real.astype(np.float32), np.clip(render, 0.0, 1.0)

    def show(self, i: int) -> np.ndarray:
        """Show frame ``i``'s pair in the panel. -> the side-by-side image [h, 2w, 3] float32."""
        real, render = self.pair(i)
        side = np.concatenate([real, render], axis=1)
        self._image.image = (side * 255).round().astype(np.uint8)
        db = float(psnr(render[None], real[None])[0])
        self._caption.content = (f"frame **{self.subject.frame_names[i]}** ({self.subject.split[i]}): real | avatar, "
                                 f"PSNR {db:.2f} dB")
        return side
