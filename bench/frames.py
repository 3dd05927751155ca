"""``trioman bench frames``: peak memory of training on a real-capture-sized subject.

    trioman bench frames --out DIR [--frames 1500] [--size 1024] [--iterations 20]

Writes a generated subject of that size (a ~10k-vertex ellipsoid body, one joint, a textured disc per
frame; frames made one at a time), then trains on it in this process and prints the wall time and the
peak resident memory (VmHWM) of each stage; a subject already in DIR/subject is reused. Issue 14's budget:
at most 4 GB for 1,500 frames at 1024 x 1024.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from trioman.bench.config import FramesBenchConfig
from trioman.runtime.formats import save_subject
from trioman.runtime.skeleton import Skeleton, SkinnedMesh
from trioman.runtime.stages import StageLog, mib, peak_rss_bytes


def write_subject(out: Path, frames: int, size: int, seed: int = 0) -> None:
    import trimesh

    sphere = trimesh.creation.icosphere(subdivisions=5)  # 10,242 vertices
    verts = np.asarray(sphere.vertices) * (0.25, 0.15, 0.85) + (0.0, 0.0, 0.9)
    V = len(verts)
    body = SkinnedMesh(Skeleton(("root",), np.array([-1]), np.array([[0.0, 0.0, 0.9]])), verts,
                       np.asarray(sphere.faces), np.zeros((V, 1), np.int32), np.ones((V, 1), np.float32))
    rng = np.random.default_rng(seed)
    f = 1.2 * size
    K = np.tile(np.array([[f, 0, size / 2], [0, f, size / 2], [0, 0, 1]]), (frames, 1, 1))
    yy, xx = np.mgrid[:size, :size] / size
    mask = (((xx - 0.5) / 0.2) ** 2 + ((yy - 0.5) / 0.45) ** 2 < 1).astype(np.float32)
    angles = np.linspace(0, 2 * np.pi, frames, endpoint=False)
    view = np.tile(np.eye(4), (frames, 1, 1))
    for i, a in enumerate(angles):  # an orbit at 3 m, looking at the body's centre
        c = np.array([3 * np.sin(a), -3 * np.cos(a), 0.9])
        z = (np.array([0.0, 0.0, 0.9]) - c) / 3
        x = np.cross(z, [0.0, 0.0, 1.0])
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        view[i, :3, :3] = np.stack([x, y, z])
        view[i, :3, 3] = -view[i, :3, :3] @ c

    def images():
        for _ in range(frames):
            colour = rng.uniform(size=3).astype(np.float32)
            yield (0.5 + 0.5 * np.sin(40 * xx + 30 * yy)[..., None].astype(np.float32) * colour) * mask[..., None]

    save_subject(out, body=body, poses=np.zeros((frames, 1, 3)), trans=np.zeros((frames, 3)), K=K, viewmat=view,
                 split=["train"] * frames, sequence=["orbit"] * frames, images=images(),
                 masks=(mask for _ in range(frames)), width=size, height=size, body_model="ellipsoid",
                 generator={"tool": "trioman.bench.frames", "seed": seed})


def bench_frames(config: FramesBenchConfig) -> dict:
    """The report of ``trioman bench frames``."""
    from trioman.bench.common import machine
    from trioman.toolkit.train.config import preset
    from trioman.toolkit.train.loop import train

    frames, iterations = config.frames, config.iterations
    out = Path(config.out)
    stages = StageLog(say=lambda line: print(f"bench frames: {line}"))
    subject = out / "subject"
    if not subject.exists():
        with stages.stage("write subject"):
            write_subject(subject, frames, config.size)
    with stages.stage("train"):
        train(subject, out / "run", preset("quick", iterations=iterations, checkpoint_every=iterations),
              progress=False)
    return {"target": "frames", "machine": machine(), "frames": frames, "size": config.size, "iterations": iterations,
            "stages": {s.name: {"seconds": round(s.seconds, 1), "peak_rss_mib": round(mib(s.peak_rss), 1)}
                       for s in stages.stages},
            "process_peak_rss_mib": round(mib(peak_rss_bytes()), 1)}


def frames_markdown(r: dict) -> str:
    lines = [f"# trioman bench frames ({r['frames']} frames at {r['size']}x{r['size']}, {r['iterations']} iterations)", "",
             f"Machine: {r['machine']}.", "", "| stage | seconds | peak RSS (MiB) |", "|---|---|---|"]
    lines += [f"| {name} | {s['seconds']} | {s['peak_rss_mib']} |" for name, s in r["stages"].items()]
    lines += ["", f"Peak resident memory of the whole benchmark process: {r['process_peak_rss_mib']} MiB.", ""]
    return "\n".join(lines)
