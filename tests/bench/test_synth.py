"""``trioman bench synth`` end to end at a tiny size, both styles."""

import pytest

pytest.importorskip("torch")
pytest.importorskip("anny")

from trioman.bench.synth import SynthBenchConfig, bench_synth, synth_markdown  # noqa: E402


@pytest.mark.parametrize("style, aspect", [("plain", 1.0), ("realistic", 0.5625)])
def test_bench_synth_reports_every_stage(style, aspect):
    r = bench_synth(SynthBenchConfig(size=48, frames=10, style=style, aspect=aspect))
    assert r["frames_written"] == 10 and r["style"] == style and r["height"] == 48
    assert r["width"] == (48 if style == "plain" else 28)
    for key in ("total_s", "body_model_s", "appearance_s", "render_ms_per_frame", "peak_rss_mib"):
        assert r[key] > 0, key
    md = synth_markdown(r)
    assert f"trioman bench synth --style {style} --size 48" in md and f"{r['total_s']} s" in md
