"""``trioman bench synth``: time per stage and peak memory of synthesising a subject."""

from __future__ import annotations


from trioman.bench.common import machine
from trioman.bench.config import SynthBenchConfig
from trioman.runtime.stages import lifetime_peak_rss_bytes, mib


TARGET_S = {"plain": 120, "realistic": 180}  # end-to-end wall time of 300 frames (plain at 256 px, realistic at 540p)


def bench_synth(config: SynthBenchConfig) -> dict:
    import shutil
    import tempfile
    import time
    from pathlib import Path

    from trioman.toolkit.synth.subject import SubjectRenderer, SynthConfig, build_body, plan_sequences, synthesize_subject

    cfg = SynthConfig(seed=config.seed, size=config.size, frames=config.frames, style=config.style, aspect=config.aspect)
    work = Path(tempfile.mkdtemp(prefix="trioman-bench-"))
    try:
        t0 = time.perf_counter()
        subject = synthesize_subject(cfg, work / "subject", progress=True, video=work / "video.mp4" if cfg.style != "plain" else None)
        total = time.perf_counter() - t0
        peak = mib(lifetime_peak_rss_bytes())
        # Stage breakdown, measured again separately in this process (the end-to-end number above is the one that counts).
        t = time.perf_counter()
        mesh, _ = build_body(cfg)
        t_body = time.perf_counter() - t
        t = time.perf_counter()
        renderer = SubjectRenderer(cfg, mesh)
        t_look = time.perf_counter() - t
        seq = plan_sequences(mesh, cfg)
        viewmat = renderer.cameras(seq.viewmat)
        n = min(30, cfg.frames)
        t = time.perf_counter()
        for i in range(n):
            renderer.recorded(i, seq, viewmat)
        t_render = (time.perf_counter() - t) / n
        return {
            "target": "synth", "machine": machine(), "size": cfg.size, "width": cfg.width, "height": cfg.height,
            "style": cfg.style, "aspect": cfg.aspect, "frames": cfg.frames, "frames_written": subject.num_frames, "total_s": round(total, 2),
            "peak_rss_mib": round(peak, 1), "body_model_s": round(t_body, 3), "appearance_s": round(t_look, 3),
            "render_ms_per_frame": round(1e3 * t_render, 2), "target_total_s": TARGET_S[cfg.style],
        }
    finally:
        shutil.rmtree(work, ignore_errors=True)


def synth_markdown(r: dict) -> str:
    ok = "yes" if r["total_s"] <= r["target_total_s"] else "NO"
    look = "texture bake" if r["style"] == "plain" else "outfit, skin texture and room"
    aspect = "" if r["aspect"] == 1 else f" --aspect {r['aspect']}"
    return "\n".join([
        f"# trioman bench synth ({r['style']}, {r['width']}x{r['height']}, {r['frames']} frames)",
        "",
        f"Machine: {r['machine']}. Command: `trioman bench synth --style {r['style']} --size {r['size']}{aspect} "
        f"--frames {r['frames']}`.",
        "",
        "| quantity | value |",
        "|---|---|",
        f"| end-to-end `synth` wall time (realistic: with `--video`) | {r['total_s']} s (target <= {r['target_total_s']} s "
        f"at 300 frames: {ok}) |",
        f"| peak resident memory (whole process) | {r['peak_rss_mib']} MiB |",
        f"| body model (Anny, cached) | {r['body_model_s']} s |",
        f"| {look} | {r['appearance_s']} s |",
        f"| one frame, one process (2x2 supersampled; realistic: shutter samples, room, sensor) | {r['render_ms_per_frame']} ms |",
        "",
    ])
