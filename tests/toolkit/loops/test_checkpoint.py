"""The settings every training loop's config shares are checked in one place and named when bad."""

import pytest

from trioman.toolkit.examiner.loop import ExaminerTrainConfig
from trioman.toolkit.refiner.loop import RefinerTrainConfig
from trioman.toolkit.train.config import TrainConfig


@pytest.mark.parametrize("config", [TrainConfig, RefinerTrainConfig, ExaminerTrainConfig])
@pytest.mark.parametrize("field", ["checkpoint_every", "keep_checkpoints", "max_skipped"])
@pytest.mark.parametrize("value", [0, -3, True, 2.5])
def test_loop_settings_must_be_positive_integers(config, field, value):
    with pytest.raises(ValueError, match=f"{field}: must be a positive integer, got {value!r}"):
        config(**{field: value})


@pytest.mark.parametrize("config", [TrainConfig, RefinerTrainConfig, ExaminerTrainConfig])
def test_positive_integers_pass(config):
    cfg = config(checkpoint_every=1, keep_checkpoints=1, max_skipped=1)
    assert (cfg.checkpoint_every, cfg.keep_checkpoints, cfg.max_skipped) == (1, 1, 1)
