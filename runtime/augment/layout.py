"""The output folder of an augment run: its names, format and version, the stages it times, and its JSON text."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from trioman import __version__
from trioman.runtime.pseudo_gt import STAGES as STEP_STAGES

AUGMENT_FORMAT = "trioman-augment"
AUGMENT_VERSION = 1
AUGMENT_JSON = "augment.json"
RECORDS_DIR = "records"
HISTOGRAM_PNG = "scores.png"
STAGES = STEP_STAGES + ("write",)


def record_path(out: Path, name: str) -> Path:
    """Where source frame ``name``'s record lies in the output folder ``out``."""
    return out / RECORDS_DIR / f"{name}.json"


def dump(obj: Any) -> str:
    """The JSON text of a record or augment.json."""
    return json.dumps(obj, indent=2, allow_nan=False) + "\n"


def versions() -> dict[str, str]:
    import onnxruntime

    return {"trioman": __version__, "numpy": np.__version__, "opencv": cv2.__version__,
            "onnxruntime": onnxruntime.__version__}


def running_header(settings: dict[str, Any]) -> dict[str, Any]:
    """augment.json while the run is going (``assemble.finish`` completes it)."""
    return {"format": AUGMENT_FORMAT, "version": AUGMENT_VERSION, "status": "running", "settings": settings,
            "versions": versions()}
