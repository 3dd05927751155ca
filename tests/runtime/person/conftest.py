"""Fixtures of the person-model tests: the models (skipped with the install line where they are not installed)
and real pictures of people that ship with packages (never committed here)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from trioman.runtime.person.models import MissingModelsError, PoseModels, load_models

OPENCV_DOC = Path("/usr/share/doc/opencv-doc/examples/data")  # Debian's opencv-doc: apt-get install opencv-doc


@pytest.fixture(scope="session")
def models() -> PoseModels:
    try:
        return load_models()
    except MissingModelsError as err:
        pytest.skip(str(err))


@pytest.fixture(scope="session")
def astronaut() -> np.ndarray:
    """scikit-image's astronaut: a woman seen from the waist up, uint8 [512, 512, 3]."""
    data = pytest.importorskip("skimage.data")
    try:
        return data.astronaut()
    except Exception as err:  # a trimmed scikit-image without its bundled pictures
        pytest.skip(f"skimage.data.astronaut() is not available: {err}")


def opencv_doc_picture(name: str) -> np.ndarray:
    """One of opencv-doc's example pictures as uint8 RGB, or a skip naming the package."""
    path = OPENCV_DOC / name
    if not path.is_file():
        pytest.skip(f"{path} is absent (apt-get install opencv-doc)")
    return cv2.cvtColor(cv2.imread(str(path)), cv2.COLOR_BGR2RGB)
