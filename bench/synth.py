"""``trioman bench synth``: time per stage and peak memory of synthesising a subject."""

from __future__ import annotations

from dataclasses import dataclass

from trioman.bench.common import check_int, machine, peak_rss_mib


@dataclass(frozen=True)
class SynthBenchConfig:
    seed: int = 0  # the subject's seed
    size: int = 256  # image side, pixels
    frames: int = 300  # subject frames

    def __post_init__(self) -> None:
        check_int(self, "seed", 0)
        check_int(self, "size")
        check_int(self, "frames")


def bench_synth(config: SynthBenchConfig) -> dict:
    import shutil
    import tempfile
    import time
    from pathlib import Path

    from trioman.toolkit.synth.shading import render_textured
    from trioman.toolkit.synth.subject import SynthConfig, build_body, plan_sequences, synthesize_subject
    from trioman.toolkit.synth.texture import bake_texture

    cfg = SynthConfig(seed=config.seed, size=config.size, frames=config.frames)
    work = Path(tempfile.mkdtemp(prefix="trioman-bench-"))
    try:
        t0 = time.perf_counter()
        subject = synthesize_subject(cfg, work / "subject", progress=True)
        total = time.perf_counter() - t0
        peak = peak_rss_mib()
        # Stage breakdown, measured again separately (the end-to-end number above is the one that counts).
        t = time.perf_counter()
        mesh, _ = build_body(cfg)
        t_body = time.perf_counter() - t
        t = time.perf_counter()
        texture = bake_texture(mesh, cfg.seed, cfg.texture_size)
        t_tex = time.perf_counter() - t
        seq = plan_sequences(mesh, cfg)
        n = min(30, cfg.frames)
        t = time.perf_counter()
        verts = [mesh.pose(seq.pose[i], seq.trans[i]) for i in range(n)]
        t_pose = (time.perf_counter() - t) / n
        t = time.perf_counter()
        for i in range(n):
            render_textured(mesh, verts[i], texture, seq.viewmat[i], seq.K[i], cfg.size, cfg.size, cfg.supersample)
        t_render = (time.perf_counter() - t) / n
        return {
            "target": "synth", "machine": machine(), "size": cfg.size, "frames": cfg.frames,
            "frames_written": subject.num_frames, "total_s": round(total, 2), "peak_rss_mib": round(peak, 1),
            "body_model_s": round(t_body, 3), "texture_bake_s": round(t_tex, 3),
            "pose_ms_per_frame": round(1e3 * t_pose, 2), "render_ms_per_frame": round(1e3 * t_render, 2),
            "target_total_s": 120,
        }
    finally:
        shutil.rmtree(work, ignore_errors=True)


def synth_markdown(r: dict) -> str:
    ok = "yes" if r["total_s"] <= r["target_total_s"] else "NO"
    return "\n".join([
        f"# trioman bench synth ({r['size']}x{r['size']}, {r['frames']} frames)",
        "",
        f"Machine: {r['machine']}. Command: `trioman bench synth --size {r['size']} --frames {r['frames']}`.",
        "",
        "| quantity | value |",
        "|---|---|",
        f"| end-to-end `synth` wall time | {r['total_s']} s (target <= {r['target_total_s']} s: {ok}) |",
        f"| peak resident memory (whole process) | {r['peak_rss_mib']} MiB |",
        f"| body model (Anny, cached) | {r['body_model_s']} s |",
        f"| texture bake | {r['texture_bake_s']} s |",
        f"| LBS per frame | {r['pose_ms_per_frame']} ms |",
        f"| render per frame (2x2 supersampled) | {r['render_ms_per_frame']} ms |",
        "",
    ])
