"""The person model against MediaPipe itself: ``mediapipe.solutions.pose`` (model_complexity 1, static images,
with segmentation), the graph this package re-implements, on real pictures. The reference runs in this
process only where the mediapipe 0.10.21 wheel and a protobuf below 7 are installed (``make install``);
elsewhere the test skips and says why.

Measured here (docs/fit.md): the detector's score and keypoints agree to 1e-6; keypoints 0.4-0.6 px apart
on average, 4.4 px at most (the astronaut, whose crop has ~5 frame px per crop px); visibility 5e-4, world
landmarks 6e-4 m; mask IoU >= 0.998.
"""

import numpy as np
import pytest

from tests.runtime.person.conftest import opencv_doc_picture
from trioman.runtime.person import PersonTracker
from trioman.runtime.person.detector import detect

MAX_PX, MEAN_PX = 6.0, 1.0  # keypoints, frame pixels
VISIBILITY = 0.005
WORLD_M = 0.002
MASK_IOU = 0.99


@pytest.fixture(scope="module")
def reference():
    """mediapipe.solutions.pose's graph as a function: image -> (landmarks, world, mask, first detection)."""
    mp = pytest.importorskip("mediapipe", reason="the reference is the mediapipe 0.10.21 wheel: make install")
    try:
        from mediapipe.python import solution_base
        from mediapipe.python.solutions import pose

        graph = solution_base.SolutionBase(
            binary_graph_path=pose._BINARYPB_FILE_PATH,  # what mp.solutions.pose.Pose runs, plus the detection
            side_inputs={"model_complexity": 1, "smooth_landmarks": False, "enable_segmentation": True,
                         "smooth_segmentation": False, "use_prev_landmarks": False},
            outputs=["pose_landmarks", "pose_world_landmarks", "segmentation_mask", "pose_detection"])
    except Exception as err:  # protobuf 7 breaks mediapipe 0.10.21's Python side
        pytest.skip(f"mediapipe {mp.__version__}'s solutions do not run here ({type(err).__name__}: {err}); "
                    "they need protobuf < 7 (pip install 'protobuf>=6.31.1,<7')")
    yield graph.process
    graph.close()


@pytest.mark.parametrize("name", ["astronaut", "messi5.jpg", "basketball1.png"])
def test_matches_mediapipe(name, reference, models, astronaut):
    image = astronaut if name == "astronaut" else opencv_doc_picture(name)
    h, w = image.shape[:2]
    ref = reference({"image": image})
    # The detector: the first detection, the one MediaPipe crops from.
    found = detect(models.detector, image)[0]
    loc = ref.pose_detection.location_data
    assert found.score == pytest.approx(ref.pose_detection.score[0], abs=1e-5)
    np.testing.assert_allclose(found.keypoints / [w, h], [[k.x, k.y] for k in loc.relative_keypoints], atol=1e-5)
    # The landmarks, world landmarks and mask of the tracker's first frame (static: detector, then crop).
    out = PersonTracker(models=models)(image)
    assert out.keypoints is not None
    want = np.array([[p.x * w, p.y * h] for p in ref.pose_landmarks.landmark])  # [33, 2] px
    err = np.linalg.norm(out.keypoints - want, axis=1)
    assert err.max() < MAX_PX and err.mean() < MEAN_PX, (err.max(), err.mean())
    visibility = np.array([p.visibility for p in ref.pose_landmarks.landmark])
    np.testing.assert_allclose(out.confidence, visibility, atol=VISIBILITY)
    world = np.array([[p.x, p.y, p.z] for p in ref.pose_world_landmarks.landmark])
    np.testing.assert_allclose(out.world, world, atol=WORLD_M)
    a, b = out.mask >= 0.5, ref.segmentation_mask >= 0.5
    assert (a & b).sum() / (a | b).sum() > MASK_IOU
