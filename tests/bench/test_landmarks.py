"""``trioman bench landmarks`` end to end at a tiny size."""

import pytest

from tests.conftest import skip_without_person_models

pytest.importorskip("torch")
pytest.importorskip("anny")

from trioman.bench.landmarks import LandmarksBenchConfig, bench_landmarks, landmarks_markdown  # noqa: E402

skip_without_person_models()


def test_bench_landmarks_measures_every_landmark(tmp_path):
    r = bench_landmarks(LandmarksBenchConfig(out=tmp_path, subjects=1, size=256, frames=10))
    assert r["frames_used"] >= 3 and len(r["rows"]) == 27
    for row in r["rows"]:
        assert 0 <= row["best_rms"] <= row["now_rms"] + 1e-9 and row["moved_mm"] <= 120.0
    md = landmarks_markdown(r)
    assert "CALIBRATED" in md and "| 11 left_shoulder |" in md
