"""Left and right made consistent over a video. A pose model that sees one frame at a time takes a person's front
for their back now and then (long hair, a dress): it then reports the body mirrored in depth, every left landmark
labelled right and the world landmarks' depth reversed. The 2D points stay where the joints are, so exchanging the
labels (and negating the world landmarks' depth about the hips) undoes it. Its world landmarks carry the body's
yaw, which changes smoothly over neighbouring frames of a video; the mirrored reading turns a yaw ``a`` into
``pi - a``. The reading of all frames at once is the one of least cost (Viterbi over two states per frame): the
squared yaw change between neighbours per frame of gap, plus ``SWAP_COST`` for each frame read mirrored, so the
model's labels stand unless the motion disagrees. A frame near a profile view cannot be exchanged (its two readings
give about the same yaw), so a wrong reading there (the model now and then reads a back view as a profile) would
decide the frames around it; the chain may therefore step over one such frame, from its previous neighbour to its
next, for ``SKIP_COST``, more than a turn through the profile costs and less than a reading far from both sides.
"""

from __future__ import annotations

import numpy as np

# MediaPipe's 33 landmarks: the index of each landmark's mirror image (nose 0; eyes 1-6; ears 7, 8; mouth 9, 10;
# then left/right pairs 11-32)
MIRROR = np.array([0, 4, 5, 6, 1, 2, 3, 8, 7, 10, 9] + [i + 1 if i % 2 else i - 1 for i in range(11, 33)])
SWAP_COST = 0.01  # rad^2 per frame: a tie-breaker between readings that fit the motion equally
# near a profile view both readings give about the same yaw, which cannot tell them apart: the model's stands
MIN_APART = np.radians(40.0)
SKIP_COST = np.radians(30.0) ** 2  # rad^2: stepping over one profile frame's reading


def body_yaw(world: np.ndarray) -> np.ndarray:
    """World landmarks [N, 33, 3] (camera axes) -> each frame's yaw [N] (rad) from the person's left-right axis
    (shoulders and hips), NaN where the landmarks are unknown (all zeros)."""
    across = (world[:, 11] - world[:, 12]) + (world[:, 23] - world[:, 24])  # the person's left
    yaw = np.arctan2(across[:, 2], across[:, 0])
    return np.where(np.linalg.norm(across, axis=1) > 1e-6, yaw, np.nan)


def _wrap(a: np.ndarray) -> np.ndarray:
    return (a + np.pi) % (2 * np.pi) - np.pi


def swapped_frames(world: np.ndarray, frame_index: np.ndarray) -> np.ndarray:
    """Which frames' left and right labels to exchange. world [N, 33, 3], frame_index [N] (the frames' numbers in
    the video: a gap of g frames allows g times the change) -> bool [N]. Frames without world landmarks keep
    their labels and do not link their neighbours."""
    yaw = body_yaw(np.asarray(world, dtype=np.float64))
    N = len(yaw)
    known = np.flatnonzero(np.isfinite(yaw))
    out = np.zeros(N, dtype=bool)
    if len(known) < 2:
        return out
    y = np.stack([yaw[known], _wrap(np.pi - yaw[known])], 1)  # [K, 2]: as read, mirrored
    t = np.asarray(frame_index, dtype=np.float64)[known]
    profile = np.abs(_wrap(y[:, 1] - y[:, 0])) < MIN_APART
    unary = np.where(profile[:, None], [0.0, np.inf], [0.0, SWAP_COST])  # [K, 2]

    def step(a: int, b: int) -> np.ndarray:
        return _wrap(y[b][None, :] - y[a][:, None]) ** 2 / max(t[b] - t[a], 1.0)  # [from, to]

    K = len(known)
    cost = np.zeros((K, 2))
    came = np.zeros((K, 2, 2), dtype=np.int64)  # each (position, reading)'s best predecessor (position, reading)
    cost[0] = unary[0]
    for k in range(1, K):
        total = cost[k - 1][:, None] + step(k - 1, k)
        best, frm = total.min(0), np.stack([np.full(2, k - 1), total.argmin(0)], 1)
        if k >= 2 and profile[k - 1]:
            over = cost[k - 2][:, None] + step(k - 2, k) + SKIP_COST
            better = over.min(0) < best
            best = np.where(better, over.min(0), best)
            frm[better] = np.stack([np.full(2, k - 2), over.argmin(0)], 1)[better]
        cost[k], came[k] = best + unary[k], frm
    k, state = K - 1, int(cost[-1].argmin())
    while True:
        out[known[k]] = state == 1
        if k == 0:
            return out
        k, state = int(came[k, state, 0]), int(came[k, state, 1])


def exchange_sides(points: np.ndarray, swap: np.ndarray, world: bool = False) -> np.ndarray:
    """points [N, 33, ...] with the swapped frames' (bool [N]) left and right landmarks exchanged (a copy); world
    landmarks [N, 33, 3] (hip-centred, camera axes) also get their depth negated."""
    out = np.array(points, copy=True)
    out[swap] = out[swap][:, MIRROR]
    if world:
        out[swap, :, 2] *= -1.0
    return out
