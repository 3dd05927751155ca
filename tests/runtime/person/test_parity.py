"""The person model against MediaPipe itself: the pose graph that ``mediapipe.solutions.pose`` runs
(mediapipe/modules/pose_landmark/pose_landmark_cpu.binarypb from the mediapipe 0.10.21 wheel; model_complexity
1, static images, segmentation on), run by ``mediapipe.CalculatorGraph`` straight from that file, on real
pictures (scikit-image's astronaut, Debian opencv-doc's when installed). Without the wheel (``make install``
brings it) the test skips and says why.

``mediapipe.solutions.pose.Pose`` is not the reference: it rebuilds the graph's config with the Python
protobuf first, which fails under protobuf 7 and, under protobuf 6, gives landmarks that match a 9 x 9
heatmap window (the option's default) to 0.03 px rather than the graph's ``kernel_size: 7``. Measured
(docs/fit.md): the detector to 1e-7, keypoints 0.003-0.024 px apart on average, 0.71 px at most; visibility
4e-4, world landmarks 7e-4 m; mask IoU 0.999.
"""

import os

import numpy as np
import pytest

from tests.runtime.person.conftest import opencv_doc_picture
from trioman.runtime.person import PersonTracker
from trioman.runtime.person.detector import detect

MAX_PX, MEAN_PX = 1.5, 0.1  # keypoints, frame pixels
VISIBILITY = 0.002
WORLD_M = 0.002
MASK_IOU = 0.99
STREAMS = ("pose_landmarks", "pose_world_landmarks", "pose_detection")
GRAPH = "mediapipe/modules/pose_landmark/pose_landmark_cpu.binarypb"  # mediapipe.solutions.pose's graph


@pytest.fixture(scope="module")
def reference():
    """MediaPipe's pose graph as a function: image -> its output packets by stream name."""
    mp = pytest.importorskip("mediapipe", reason="the reference is the mediapipe 0.10.21 wheel: make install")
    from mediapipe.python._framework_bindings import resource_util

    root = os.path.dirname(os.path.dirname(mp.__file__))
    resource_util.set_resource_dir(root)

    def run(image: np.ndarray) -> dict:
        graph = mp.CalculatorGraph(binary_graph_path=os.path.join(root, GRAPH))
        out = {}
        for name in STREAMS:
            graph.observe_output_stream(name, lambda n, p: out.__setitem__(n, mp.packet_getter.get_proto(p)))
        graph.observe_output_stream("segmentation_mask", lambda n, p: out.__setitem__(
            n, np.array(mp.packet_getter.get_image_frame(p).numpy_view(), copy=True)))
        side = {name: mp.packet_creator.create_bool(False)  # static images: no smoothing, no previous landmarks
                for name in ("smooth_landmarks", "smooth_segmentation", "use_prev_landmarks")}
        side["enable_segmentation"] = mp.packet_creator.create_bool(True)
        side["model_complexity"] = mp.packet_creator.create_int(1)
        graph.start_run(side)
        graph.add_packet_to_input_stream("image", mp.packet_creator.create_image_frame(
            image_format=mp.ImageFormat.SRGB, data=image).at(0))
        graph.close()
        return out

    return run


@pytest.mark.parametrize("name", ["astronaut", "messi5.jpg", "basketball1.png"])
def test_matches_mediapipe(name, reference, models, astronaut):
    image = astronaut if name == "astronaut" else opencv_doc_picture(name)
    h, w = image.shape[:2]
    ref = reference(image)
    # The detector: the first detection, the one MediaPipe crops from.
    found = detect(models.detector, image)[0]
    loc = ref["pose_detection"].location_data
    assert found.score == pytest.approx(ref["pose_detection"].score[0], abs=1e-5)
    np.testing.assert_allclose(found.keypoints / [w, h], [[k.x, k.y] for k in loc.relative_keypoints], atol=1e-5)
    # The landmarks, world landmarks and mask of the tracker's first frame (static: detector, then crop).
    out = PersonTracker(models=models)(image)
    assert out.keypoints is not None
    want = np.array([[p.x * w, p.y * h] for p in ref["pose_landmarks"].landmark])  # [33, 2] px
    err = np.linalg.norm(out.keypoints - want, axis=1)
    assert err.max() < MAX_PX and err.mean() < MEAN_PX, (err.max(), err.mean())
    visibility = np.array([p.visibility for p in ref["pose_landmarks"].landmark])
    np.testing.assert_allclose(out.confidence, visibility, atol=VISIBILITY)
    world = np.array([[p.x, p.y, p.z] for p in ref["pose_world_landmarks"].landmark])
    np.testing.assert_allclose(out.world, world, atol=WORLD_M)
    a, b = out.mask >= 0.5, ref["segmentation_mask"] >= 0.5
    assert (a & b).sum() / (a | b).sum() > MASK_IOU
