"""``trioman bench landmarks`` end to end at a tiny size."""

import numpy as np
import pytest

from tests.conftest import skip_without_person_models

pytest.importorskip("torch")
pytest.importorskip("anny")

from trioman.bench.landmarks import LandmarksBenchConfig, bench_landmarks, landmarks_markdown  # noqa: E402

skip_without_person_models()


def test_bench_landmarks_measures_every_landmark(tmp_path):
    r = bench_landmarks(LandmarksBenchConfig(out=tmp_path, subjects=2, size=256, frames=10))
    assert r["frames_used"] >= 6 and len(r["rows"]) == 27
    joints = [row for row in r["rows"] if row["point"] != "vertex"]
    assert len(joints) == 20
    for row in joints:
        assert 0 < row["offset_rms"] <= row["joint_rms"] + 1e-9  # least squares on the same frames cannot do worse
        assert max(abs(v) for v in row["offset_mm"]) < 150.0 and row["heldout_offset_rms"] > 0
    md = landmarks_markdown(r)
    assert "JOINT_OFFSETS" in md and "| 11 left_shoulder |" in md


def test_the_offset_fit_recovers_a_planted_offset():
    """Residuals made by a known offset through known Jacobians (plus outliers the cut drops) give it back."""
    from trioman.bench.landmarks import _Frames, fit_offset, offset_rms

    rng = np.random.default_rng(0)
    d = np.array([0.01, -0.03, 0.04])
    f = _Frames([], [], [], [], [], [])
    for k in range(40):
        J = rng.normal(scale=400.0, size=(1, 2, 3))
        r = J[0] @ d + rng.normal(scale=0.5, size=2)
        if k % 10 == 0:
            r = r + 300.0  # a reading of the other side: beyond the cut
        f.residual.append(r[None]), f.jacobian.append(J), f.confidence.append(np.ones(1)), f.height.append(400.0)
    np.testing.assert_allclose(fit_offset([f], 0), d, atol=2e-3)
    assert offset_rms([f], 0, fit_offset([f], 0)) < 0.1 * offset_rms([f], 0, np.zeros(3))
