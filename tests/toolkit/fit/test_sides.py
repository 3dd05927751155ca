"""Left and right made consistent over a video: frames read mirrored (front taken for back) are found from the
world landmarks' yaw over time, and exchanging their sides restores them."""

import numpy as np
import pytest

from trioman.toolkit.fit.sides import MIRROR, body_yaw, exchange_sides, swapped_frames


def turning_world(yaw_deg: np.ndarray, seed: int = 0, noise: float = 0.01) -> np.ndarray:
    """World landmarks [N, 33, 3] (camera axes: x right, y down, z away) of a person turning in place: the person's
    left shoulder and hip at +x when facing the camera (yaw 0), turning about the vertical (-y) axis."""
    rng = np.random.default_rng(seed)
    rest = np.zeros((33, 3))
    rest[11], rest[12] = (0.2, -0.5, 0.0), (-0.2, -0.5, 0.0)
    rest[23], rest[24] = (0.1, 0.0, 0.0), (-0.1, 0.0, 0.0)
    rest[13], rest[14] = (0.25, -0.25, -0.05), (-0.25, -0.25, -0.05)
    rest[0] = (0.0, -0.65, -0.1)  # the nose, towards the camera
    out = []
    for a in np.radians(yaw_deg):
        c, s = np.cos(a), np.sin(a)
        R = np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]])  # +x (the left) turns towards +z
        out.append(rest @ R.T + noise * rng.standard_normal((33, 3)))
    return np.stack(out)


def test_mirror_pairs_each_left_landmark_with_its_right():
    assert MIRROR[0] == 0 and np.array_equal(MIRROR[MIRROR], np.arange(33))
    assert (MIRROR[11], MIRROR[16], MIRROR[23], MIRROR[32], MIRROR[7], MIRROR[1], MIRROR[9]) == (12, 15, 24, 31, 8, 4, 10)


def test_body_yaw_follows_the_turn_and_is_nan_when_unknown():
    yaw = np.array([0.0, 30.0, 90.0, 150.0, -120.0])
    world = turning_world(yaw, noise=0.0)
    np.testing.assert_allclose(np.degrees(body_yaw(world)), yaw, atol=1e-6)
    world[2] = 0.0
    assert np.isnan(body_yaw(world)[2]) and np.isfinite(body_yaw(world)[[0, 1, 3, 4]]).all()


@pytest.mark.parametrize("block", [slice(0, 12), slice(140, 175), slice(290, 300)])
def test_frames_read_mirrored_are_found_and_given_their_sides_back(block):
    yaw = np.arange(300) * 1.2  # a full turn in 300 frames
    truth = turning_world(yaw)
    mirrored = np.zeros(300, dtype=bool)
    mirrored[block] = True  # near the front (0-14 deg, 348-359 deg) or the back (168-209 deg): readings far apart
    seen = exchange_sides(truth, mirrored, world=True)  # what the pose model reports: sides exchanged, depth reversed
    assert not np.allclose(seen[mirrored], truth[mirrored])
    found = swapped_frames(seen, np.arange(300))
    np.testing.assert_array_equal(found, mirrored)
    np.testing.assert_allclose(exchange_sides(seen, found, world=True), truth)


def test_a_consistent_video_is_left_as_it_is():
    yaw = 40 * np.sin(np.linspace(0, 3 * np.pi, 200))  # turning back and forth in front of the camera
    assert not swapped_frames(turning_world(yaw, seed=1), np.arange(200)).any()
    full = np.arange(0, 600, 3) * 1.2  # every third frame of two full turns
    assert not swapped_frames(turning_world(full, seed=2), np.arange(0, 600, 3)).any()


def test_profile_views_and_unknown_frames_keep_the_models_reading():
    yaw = 90 + np.zeros(50)
    world = turning_world(yaw, seed=3, noise=0.02)  # the two readings agree within the noise: nothing to decide
    world[10:20] = 0.0  # no world landmarks
    assert not swapped_frames(world, np.arange(50)).any()
    assert not swapped_frames(np.zeros((1, 33, 3)), np.arange(1)).any()


def test_a_wrong_reading_near_profile_does_not_decide_its_neighbours():
    """The pose model now and then reads a back view as a profile one (s2102 of `bench fit`: frames at 157 and
    180 degrees read as 71 and -74). Such a reading cannot be exchanged (its mirror image is as near profile), so
    the chain may step over it: as a link it made the frames around it cheaper read mirrored, and the whole back
    view of the turn was fitted as a front view."""
    yaw = 100.0 + np.arange(120) * 1.2  # from past the profile through the back
    seen = turning_world(yaw, seed=4)
    glitch = turning_world(np.array([72.0, -74.0]), seed=5)
    seen[[30, 70]] = glitch  # two readings near profile, far from the turn
    found = swapped_frames(seen, np.arange(120))
    assert not found.any(), np.flatnonzero(found)
    mirrored = np.zeros(120, dtype=bool)
    mirrored[40:46] = True  # a short stretch read mirrored among them is still found
    found = swapped_frames(exchange_sides(seen, mirrored, world=True), np.arange(120))
    np.testing.assert_array_equal(found, mirrored)
    # a quick half turn (5.6 degrees a frame) read mirrored at its start: the readings through the profile, right
    # ones, still carry the turn from one side to the other
    half = turning_world(np.arange(32) * 5.6, seed=6)
    mirrored = np.arange(32) < 4
    np.testing.assert_array_equal(swapped_frames(exchange_sides(half, mirrored, world=True), np.arange(32)), mirrored)
