"""The tiny avatar configuration of the training tests and a run's losses. Import it after ``pytest.importorskip("torch")``: the
configuration class comes from the torch avatar model."""

import csv

import numpy as np

from trioman.toolkit.avatar.model import AvatarConfig

TINY_AVATAR = AvatarConfig(keep=0.3, triplane_channels=4, triplane_res=16, hidden=32)


def losses(run) -> np.ndarray:
    """The losses of a run's train_log.csv."""
    with open(run / "train_log.csv") as f:
        return np.array([float(r["loss"]) for r in csv.DictReader(f)])
