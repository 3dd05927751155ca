"""Fabricated triplet files (random images of side S) for the tests of the Refiner/Examiner training glue and of
the benchmarks, built without torch."""

import json

import numpy as np

S = 32


def fake_triplets(path, seed, n=8):
    rng = np.random.default_rng(seed)
    img = lambda: rng.integers(0, 256, (n, S, S, 3), dtype=np.uint8)  # noqa: E731
    np.savez(path, meta=np.array(json.dumps({"version": 2})), gt=img(), coarse=img(), normal=img(),
             mask=rng.integers(0, 256, (n, S, S), dtype=np.uint8), frame=np.arange(n, dtype=np.int32),
             split=np.array(["train"] * (n - 3) + ["test"] * 3), sequence=np.array(["a"] * (n - 3) + ["b"] * 3),
             view_yaw=rng.uniform(-3, 3, n).astype(np.float32), aligned=img(),
             valid=(rng.random((n, S, S)) < 0.5).astype(np.uint8) * 255, aligned_from=(np.arange(n, dtype=np.int32) + 1) % n)
