"""A turntable MP4 of a synthetic subject's posed, textured mesh: the camera orbits once while the
body plays the test motions (the preview a person looks at first)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from tqdm import tqdm

from trioman.runtime import motions
from trioman.runtime.cameras import orbit_viewmat
from trioman.runtime.image_io import write_video
from trioman.toolkit.synth.shading import render_textured
from trioman.toolkit.synth.subject import SynthConfig, build_body, framing_intrinsics
from trioman.toolkit.synth.texture import bake_texture


def write_turntable(cfg: SynthConfig, path: str | Path, frames: int = 96, fps: float = 24.0, progress: bool = True) -> Path:
    mesh, _ = build_body(cfg)
    texture = bake_texture(mesh, seed=cfg.seed, size=cfg.texture_size)
    per = -(-frames // len(motions.TEST_MOTIONS))
    clips = [make(mesh.skeleton, per) for make in motions.TEST_MOTIONS.values()]
    pose = np.concatenate([c.pose for c in clips])[:frames]
    trans = np.concatenate([c.trans for c in clips])[:frames]
    center = np.array([0.0, 0.0, 0.5 * (mesh.vertices[:, 2].min() + mesh.vertices[:, 2].max())])
    K = framing_intrinsics(mesh, cfg)

    def render():
        for i in tqdm(range(frames), desc="turntable", unit="frame", disable=None if progress else True):
            view = orbit_viewmat(center, 2 * np.pi * i / frames, np.deg2rad(10.0), 3.4)
            rgb, mask = render_textured(mesh, mesh.pose(pose[i], trans[i]), texture, view, K, cfg.size, cfg.size, cfg.supersample)
            yield rgb + (1.0 - mask[..., None]) * 0.92  # light grey background

    write_video(path, render(), fps=fps)
    return Path(path)
