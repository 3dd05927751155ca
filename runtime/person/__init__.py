"""The person in each video frame, from MediaPipe's pose models under LiteRT (numpy + OpenCV + ai-edge-litert,
never torch, never the mediapipe package's code): box, 33 keypoints with confidences, world landmarks, mask.

    models    find the .tflite files in the installed mediapipe 0.10.21 wheel, check them, load them
    warp      the models' input crops, resampled as MediaPipe's OpenCV 4 warp does
    detector  SSD anchors, box decoding, weighted NMS: the people in a frame
    landmarks the crop from two points, the landmark model, keypoints / world landmarks / mask in the frame
    tracker   ``PersonTracker``: the crop carried from frame to frame, a verdict per frame

Install: ``pip install 'trioman[fit]' && pip install --no-deps mediapipe==0.10.21`` (``make install`` does
both); docs/fit.md, "Per-frame person model".
"""

from trioman.runtime.person.models import MissingModelsError, load_models
from trioman.runtime.person.tracker import STATUSES, PersonFrame, PersonTracker, TrackerConfig

__all__ = ["MissingModelsError", "PersonFrame", "PersonTracker", "STATUSES", "TrackerConfig", "load_models"]
