"""A run forked from its unaugmented control's warm-up goes on to the weights of the same run from scratch
(toolkit/train/fork.py), and a fork that could not is refused naming why."""

import dataclasses
import json

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("anny")

from tests.toolkit.train.factories import TINY_AVATAR, losses  # noqa: E402
from trioman.toolkit.loops.checkpoint import list_checkpoints, load_checkpoint  # noqa: E402
from trioman.toolkit.train.augmentation import AugmentConfig  # noqa: E402
from trioman.toolkit.train.config import TrainConfig  # noqa: E402
from trioman.toolkit.train.fork import fork_run, fork_step  # noqa: E402
from trioman.toolkit.train.loop import AUGMENT_JSON, train  # noqa: E402

def _weights(run):
    return load_checkpoint(list_checkpoints(run)[-1])["model"]


@pytest.mark.parametrize("mode", [None, "aligned", "examined"])
def test_a_fork_at_the_warm_up_matches_the_run_from_scratch(subject, models, tmp_path, mode, two_threads):
    aug = None if mode is None else AugmentConfig(
        mode=mode, start=0.5, refresh=2, pool=2, share=0.6,
        **({"refiner": str(models["refiner"]), "examiner": str(models["examiner"])} if mode == "examined" else {}))
    cfg = TrainConfig(iterations=10, checkpoint_every=10, avatar=TINY_AVATAR, augment=aug)
    step = 5 if mode else 4
    assert fork_step(cfg) == (5 if mode else 10)
    warm = dataclasses.replace(cfg, augment=None, checkpoint_every=step)
    train(subject, tmp_path / "warm", warm, progress=False, stop_after=step)
    forked = fork_run(tmp_path / "warm", tmp_path / "fork", cfg, step)
    record = json.loads((forked / "config.json").read_text())
    assert record["forked_from"] == {"run": str((tmp_path / "warm").resolve()), "step": step}
    train(subject, forked, cfg, resume=True, progress=False)
    scratch = train(subject, tmp_path / "scratch", cfg, progress=False)
    a, b = _weights(scratch), _weights(forked)
    for key in a:
        assert torch.equal(a[key], b[key]), key
    np.testing.assert_array_equal(losses(scratch), losses(forked))
    assert len(losses(forked)) == 10
    if mode:
        sa, sb = (json.loads((r / AUGMENT_JSON).read_text()) for r in (scratch, forked))
        assert sa["pseudo_steps"] > 0 and {k: sa[k] for k in ("rebuilds", "pseudo_steps", "kept")} == \
            {k: sb[k] for k in ("rebuilds", "pseudo_steps", "kept")}


def test_a_fork_that_would_not_match_is_refused(subject, tmp_path, two_threads):
    aug = AugmentConfig(mode="aligned", start=0.5, refresh=2, pool=2)
    cfg = TrainConfig(iterations=8, checkpoint_every=8, avatar=TINY_AVATAR, augment=aug)
    warm = train(subject, tmp_path / "warm", dataclasses.replace(cfg, augment=None, checkpoint_every=2), progress=False,
                 stop_after=6)
    with pytest.raises(ValueError, match=r"^step: a fork starts within the augmentation's warm-up, 1..4, got 6"):
        fork_run(warm, tmp_path / "f1", cfg, 6)
    with pytest.raises(ValueError, match=r"differs in more than augmentation \(lr: 0.001 -> 0.002\)"):
        fork_run(warm, tmp_path / "f2", dataclasses.replace(cfg, lr=2e-3), 4)
    with pytest.raises(FileNotFoundError, match="ckpt_0000003.pt: no such checkpoint"):
        fork_run(warm, tmp_path / "f3", cfg, 3)
    aug_run = fork_run(warm, tmp_path / "f4", cfg, 4)
    with pytest.raises(ValueError, match="trains with augmentation; fork from an unaugmented run"):
        fork_run(aug_run, tmp_path / "f5", cfg, 4)
    with pytest.raises(FileExistsError, match="already exists"):
        fork_run(warm, aug_run, cfg, 4)
    torch.set_num_threads(1)
    with pytest.raises(ValueError, match="was trained with 2 torch threads, this process has 1"):
        fork_run(warm, tmp_path / "f6", cfg, 4)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f4", "warm"]  # nothing half-made
