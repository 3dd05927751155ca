"""``trioman view``'s library entry: load what the flags name, start the viewer, attach the panels."""

from __future__ import annotations

import os

from trioman.runtime.formats import load_avatar
from trioman.runtime.viewer.config import ViewerConfig
from trioman.runtime.viewer.posing import Poser, motion_catalog, motion_label
from trioman.runtime.viewer.server import AvatarViewer


def open_viewer(avatar: str | os.PathLike | None, motion: str | None = None, subject: str | os.PathLike | None = None,
                augmented: str | os.PathLike | None = None, host: str = ViewerConfig.host,
                port: int = ViewerConfig.port, fps: float | None = ViewerConfig.fps) -> AvatarViewer:
    """A running viewer of ``avatar`` (default with ``augmented``: the augment run's avatar); every input is
    loaded and checked before the server starts. Stop it with ``.stop()``."""
    from trioman.runtime.viewer.augmented import AugmentedView, run_avatar_path
    from trioman.runtime.viewer.cameras import SubjectCameras

    if avatar is None:
        if augmented is None:
            raise ValueError("avatar: give an avatar folder (or `augmented` DIR, whose run names its avatar)")
        avatar = run_avatar_path(augmented)
    av = load_avatar(avatar)
    poser = Poser(av, motion_catalog(av.skeleton, motion, subject))
    if motion is not None:
        poser.select(motion_label(motion))
    viewer = AvatarViewer(poser, ViewerConfig(host=host, port=port, fps=fps))
    try:
        if subject is not None:
            viewer.subject_cameras = SubjectCameras(viewer, subject)
        if augmented is not None:
            viewer.augmented = AugmentedView(viewer, augmented)
    except BaseException:
        viewer.stop()
        raise
    return viewer
