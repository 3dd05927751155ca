"""Training frames: 8-bit in memory or read lazily from disk, the same float32 values either way."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from trioman.runtime.formats import save_subject  # noqa: E402
from trioman.runtime.skeleton import Skeleton, SkinnedMesh  # noqa: E402
from trioman.toolkit.train.data import join_frames, load_frames  # noqa: E402


@pytest.fixture(scope="module")
def subject(tmp_path_factory):
    rng = np.random.default_rng(0)
    N, H, W = 5, 12, 16
    body = SkinnedMesh(Skeleton(("root",), np.array([-1]), np.zeros((1, 3))), rng.normal(size=(4, 3)),
                       np.array([[0, 1, 2]]), np.zeros((4, 1), np.int32), np.ones((4, 1), np.float32))
    masks = rng.uniform(size=(N, H, W)).astype(np.float32)
    images = rng.uniform(size=(N, H, W, 3)).astype(np.float32) * masks[..., None]
    view = np.tile(np.eye(4), (N, 1, 1))
    view[:, 2, 3] = 3
    K = np.tile(np.array([[20.0, 0, 8], [0, 20, 6], [0, 0, 1]]), (N, 1, 1))
    return save_subject(tmp_path_factory.mktemp("s") / "subj", body=body, poses=np.zeros((N, 1, 3)),
                        trans=np.zeros((N, 3)), K=K, viewmat=view, split=["train"] * N, sequence=["a"] * N,
                        images=images, masks=masks, width=W, height=H, body_model="test")


@pytest.mark.parametrize("scale", [1.0, 0.5])
def test_lazy_and_in_memory_frames_agree(subject, scale):
    memory = load_frames(subject, "train", scale)
    lazy = load_frames(subject, "train", scale, in_memory_bytes=0)
    assert type(memory.pixels).__name__ == "_MemoryPixels" and type(lazy.pixels).__name__ == "_DiskPixels"
    for i in range(len(memory)):
        a, b = memory.sample(i), lazy.sample(i)
        assert a["images"].dtype == torch.float32 and a["images"].shape == (memory.height, memory.width, 3)
        torch.testing.assert_close(a["images"], b["images"], rtol=0, atol=0)
        torch.testing.assert_close(a["masks"], b["masks"], rtol=0, atol=0)
    if scale == 1.0:  # the stored 8-bit values, exactly as the subject reads them
        np.testing.assert_array_equal(memory.image(2).numpy(), subject.image(2))
        np.testing.assert_array_equal(lazy.mask(2).numpy(), subject.mask(2))
    joined = join_frames(memory, lazy, 0.5)
    torch.testing.assert_close(joined.image(len(memory) + 1), lazy.image(1), rtol=0, atol=0)
