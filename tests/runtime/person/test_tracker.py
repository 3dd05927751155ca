"""PersonTracker on real pictures and on frames without a person: the verdict per frame, tracking without the
detector, the inputs it refuses, and the error that names the install when the models are missing."""

import importlib.metadata

import cv2
import numpy as np
import pytest

from tests.conftest import run_python
from tests.runtime.person.conftest import opencv_doc_picture
from trioman.runtime.person import MissingModelsError, PersonTracker, TrackerConfig
from trioman.runtime.person.models import INSTALL_HINT, MODEL_FILES, load_models, model_paths


@pytest.fixture
def tracker(models):
    return PersonTracker(models=models)


def test_no_person_is_a_status_not_an_error(tracker):
    rng = np.random.default_rng(0)
    for frame in (np.zeros((120, 90, 3), np.uint8), np.full((64, 64, 3), 255, np.uint8),
                  rng.integers(0, 256, (200, 300, 3), dtype=np.uint8)):
        out = tracker(frame)
        assert out.status == "no_person" and not out.ok, out.reason
        assert "no person" in out.reason or "person flag" in out.reason
        assert out.keypoints is None and out.box is None and out.world is None and out.detected
        assert out.mask.shape == frame.shape[:2] and out.mask.dtype == np.float32 and not out.mask.any()


def test_astronaut_is_cut_by_the_frame_edge(tracker, astronaut):
    out = tracker(astronaut)
    assert out.status == "cut_by_edge" and out.people == 1 and out.detected
    assert "left_ankle" in out.reason and "bottom" in out.reason  # her legs lie below the picture
    assert out.keypoints.shape == (33, 2) and out.confidence.shape == (33,) and out.world.shape == (33, 3)
    assert out.mask.shape == (512, 512) and 0 <= out.mask.min() and out.mask.max() <= 1
    nose, eyes = out.keypoints[0], out.keypoints[[2, 5]]
    assert 200 < nose[0] < 260 and 100 < nose[1] < 160 and (eyes[:, 1] < nose[1]).all()
    x0, y0, x1, y1 = out.box
    assert x0 <= nose[0] <= x1 and y0 <= nose[1] <= y1 and y1 == 512
    # World landmarks: metres about the hips' centre, shoulders ~0.3 m apart.
    assert 0.2 < np.linalg.norm(out.world[11] - out.world[12]) < 0.5
    np.testing.assert_allclose((out.world[23] + out.world[24]) / 2, 0, atol=0.05)


def test_two_people_and_low_confidence(models, astronaut):
    # Two astronauts (384 px) 200 px apart: the detector finds both (scores ~0.84 and ~0.81).
    small = cv2.resize(astronaut, (384, 384), interpolation=cv2.INTER_AREA)
    pair = np.full((400, 968, 3), 90, np.uint8)
    pair[:384, :384], pair[:384, 584:] = small, small
    out = PersonTracker(models=models)(pair)
    assert out.status == "two_people" and out.people == 2, out.reason
    assert out.reason.startswith("the detector found 2 people (scores 0.")
    # With the edge tests off and a person flag of 1 asked for, she is a low-confidence frame.
    strict = TrackerConfig(edge_margin=1e6, edge_mask_fraction=1.0, min_person_score=1.0)
    out = PersonTracker(strict, models=models)(astronaut)
    assert out.status == "low_confidence" and out.reason.startswith("person flag 0.9") and "(min 1)" in out.reason


def test_verdicts_on_opencv_doc_pictures(tracker):
    messi = tracker(opencv_doc_picture("messi5.jpg"))
    assert messi.status == "ok" and messi.reason == "" and messi.score > 0.99
    tracker.reset()
    two = tracker(opencv_doc_picture("basketball2.png"))  # a second player at the right edge
    assert two.status == "two_people" and two.people == 2 and "found 2 people" in two.reason


def test_tracking_runs_the_detector_once(models, astronaut):
    frame = np.full((600, 560, 3), 90, np.uint8)
    frames = []
    for i in range(6):  # the astronaut moving right and down by 3 px a frame
        f = frame.copy()
        f[40 + 3 * i:552 + 3 * i, 10 + 3 * i:522 + 3 * i] = astronaut
        frames.append(f)
    tracker = PersonTracker(models=models)
    out = list(tracker.track(frames))
    assert tracker.detector_runs == 1 and [o.detected for o in out] == [True] + [False] * 5
    assert all(o.keypoints is not None and o.score > 0.9 for o in out)
    # The head's points follow the motion, 15 px in all. Her crop is ~1250 px wide (her legs lie outside the
    # picture), ~5 px per crop pixel: a frame's estimate moves by several pixels, tracked or detected afresh.
    head = np.array([o.keypoints[:13].mean(0) for o in out])  # [6, 2]
    np.testing.assert_allclose(head[-1] - head[0], 15, atol=8)
    tracker.reset()
    np.testing.assert_allclose(tracker(frames[-1]).keypoints[:13].mean(0), head[-1], atol=8)
    # A frame of another size starts a new track; redetect_every counts people on tracked frames too.
    assert tracker(frames[0][:500]).detected and tracker.detector_runs == 3
    again = PersonTracker(TrackerConfig(redetect_every=2), models=models)
    assert [o.detected for o in again.track(frames)] == [True, False, False, True, False, False]
    # Lost (a blank frame): the detector runs on it, and on the next frame until the person is back.
    tracker.track([])
    runs = tracker.detector_runs
    statuses = [o.status for o in tracker.track([frames[0], np.zeros_like(frames[0]), frames[1], frames[2]])]
    assert statuses[1] == "no_person" and statuses[2] != "no_person"
    assert tracker.detector_runs - runs == 3


def test_bad_inputs_name_the_parameter(tracker):
    for bad, shown in ((np.zeros((8, 8, 3)), "float64 [8, 8, 3]"), (np.full((8, 8, 3), np.nan, np.float32), "float32 [8, 8, 3]"),
                       (np.zeros((8, 8), np.uint8), "uint8 [8, 8]"), (np.zeros((0, 8, 3), np.uint8), "uint8 [0, 8, 3]")):
        with pytest.raises(ValueError, match=r"^image: expected uint8 \[H, W, 3\] with H, W >= 2, got " + shown.replace("[", r"\[")):
            tracker(bad)
    cases = {"min_person_score": (1.5, r"must lie in \[0, 1\], got 1.5"), "edge_margin": (-1.0, "must be >= 0 pixels, got -1.0"),
             "second_person_score": (float("nan"), "must be a finite number, got nan"),
             "redetect_every": (-1, "must be an integer >= 0, got -1"), "threads": (0, "must be an integer >= 1, got 0"),
             "min_tracking_score": ("0.5", "must be a finite number, got '0.5'")}
    for name, (value, message) in cases.items():
        with pytest.raises(ValueError, match=f"^{name}: {message}$"):
            TrackerConfig(**{name: value})
    with pytest.raises(ValueError, match=r"^threads: must be an integer >= 1, got True$"):
        load_models(threads=True)


def test_missing_models_name_the_install(tmp_path, monkeypatch):
    with pytest.raises(MissingModelsError, match=r"pose_detection.tflite not found in .*pip install 'trioman\[fit\]' && "
                                                 r"pip install --no-deps mediapipe==0.10.21 \(or: make install\)$"):
        model_paths(tmp_path)
    for rel, _ in MODEL_FILES.values():
        (tmp_path / rel.rsplit("/", 1)[1]).write_bytes(b"not a model")
    with pytest.raises(MissingModelsError, match=r"not the file of mediapipe 0.10.21 \(sha256 [0-9a-f]{12}\.\.\.\)"):
        model_paths(tmp_path)

    def absent(name):
        raise importlib.metadata.PackageNotFoundError(name)

    monkeypatch.setattr(importlib.metadata, "distribution", absent)
    with pytest.raises(MissingModelsError) as err:
        PersonTracker()
    assert str(err.value) == ("person models: the mediapipe 0.10.21 wheel that carries the pose models is not "
                              f"installed: {INSTALL_HINT}")
    assert "\n" not in str(err.value)


def test_missing_litert_names_the_extra(models):
    # In a fresh interpreter without ai_edge_litert (and without torch): one line naming the extra.
    proc = run_python("""
        import sys
        sys.modules["ai_edge_litert"] = None
        from trioman.runtime.person import MissingModelsError, PersonTracker
        try:
            PersonTracker()
        except MissingModelsError as err:
            print(err)
    """, block_torch=True)
    assert proc.stdout.strip() == ("person models: ai-edge-litert, which runs them, is not installed: "
                                   "pip install 'trioman[fit]' && pip install --no-deps mediapipe==0.10.21 (or: make install)")


def test_runtime_imports_neither_torch_nor_mediapipe(models):
    proc = run_python("""
        import sys
        import numpy as np
        from trioman.runtime.person import PersonTracker
        out = PersonTracker()(np.zeros((64, 48, 3), np.uint8))
        print(out.status, "mediapipe" in sys.modules, sys.modules.get("torch") is not None)  # torch: blocked, None
    """, block_torch=True)
    assert proc.stdout.split() == ["no_person", "False", "False"], proc.stderr[-2000:]


def test_loading_the_models_prints_nothing(models):
    """LiteRT's delegate announcement on the C stderr is silenced; Python's stderr still works after the load."""
    proc = run_python("""
        import sys
        from trioman.runtime.person import load_models
        load_models()
        print("after", file=sys.stderr)
    """, block_torch=True)
    assert proc.returncode == 0 and proc.stderr.strip() == "after", proc.stderr
