"""The score histogram ``scores.png`` (OpenCV; no matplotlib in the runtime)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Mapping

import cv2
import numpy as np

from trioman.runtime.image_io import write_png

_COLORS = {"accepted": (46, 160, 67), "rejected": (214, 39, 40), "not_chosen": (170, 170, 170)}  # RGB
_LABELS = {"accepted": "accepted", "rejected": "rejected (below threshold)", "not_chosen": "not chosen"}


def draw_histogram(scores: Mapping[str, list[float]], threshold: float | None, path: str | os.PathLike,
                   bins: int = 20, size: tuple[int, int] = (640, 400)) -> Path:
    """Stacked histogram of Examiner scores in [0, 1] by status (accepted / rejected / not chosen), the
    threshold as a vertical line; an 8-bit RGB PNG written atomically at ``path``."""
    W, H = size
    img = np.full((H, W, 3), 255, np.uint8)
    left, right, top, bottom = 56, 20, 70, 48
    pw, ph = W - left - right, H - top - bottom
    edges = np.linspace(0.0, 1.0, bins + 1)
    counts = {k: np.histogram(np.clip(np.asarray(v, dtype=np.float64), 0.0, 1.0), bins=edges)[0]
              for k, v in scores.items() if k in _COLORS}
    total = sum(counts.values()) if counts else np.zeros(bins, int)
    ymax = max(int(np.max(total)) if np.size(total) else 0, 1)
    font, black, grey = cv2.FONT_HERSHEY_SIMPLEX, (0, 0, 0), (200, 200, 200)

    def x_of(v: float) -> int:
        return left + int(round(v * pw))

    def y_of(c: float) -> int:
        return top + ph - int(round(c / ymax * ph))

    for frac in (0.25, 0.5, 0.75, 1.0):  # grid
        cv2.line(img, (left, y_of(frac * ymax)), (left + pw, y_of(frac * ymax)), grey, 1)
    for b in range(bins):
        base = 0
        for k in ("accepted", "rejected", "not_chosen"):
            c = int(counts[k][b]) if k in counts else 0
            if c:
                cv2.rectangle(img, (x_of(edges[b]) + 1, y_of(base + c)), (x_of(edges[b + 1]) - 1, y_of(base) - 1),
                              _COLORS[k], -1)
                base += c
    cv2.line(img, (left, top + ph), (left + pw, top + ph), black, 1)  # axes
    cv2.line(img, (left, top), (left, top + ph), black, 1)
    for v in (0.0, 0.25, 0.5, 0.75, 1.0):
        cv2.line(img, (x_of(v), top + ph), (x_of(v), top + ph + 4), black, 1)
        cv2.putText(img, f"{v:g}", (x_of(v) - 10, top + ph + 18), font, 0.4, black, 1, cv2.LINE_AA)
    for c in sorted({0, ymax // 2, ymax}):
        cv2.putText(img, str(c), (left - 8 - 8 * len(str(c)), y_of(c) + 4), font, 0.4, black, 1, cv2.LINE_AA)
    cv2.putText(img, "Examiner score", (left + pw // 2 - 50, H - 12), font, 0.45, black, 1, cv2.LINE_AA)
    cv2.putText(img, "candidates", (4, top - 10), font, 0.4, black, 1, cv2.LINE_AA)
    if threshold is not None:
        x = x_of(float(threshold))
        for y in range(top, top + ph, 8):  # dashed
            cv2.line(img, (x, y), (x, min(y + 4, top + ph)), (31, 119, 180), 2)
        cv2.putText(img, f"threshold {threshold:.3g}", (min(x + 4, W - 110), top + 12), font, 0.4, (31, 119, 180), 1,
                    cv2.LINE_AA)
    n_all = sum(len(v) for v in scores.values())
    cv2.putText(img, f"Examiner scores of {n_all} refined candidates", (8, 20), font, 0.5, black, 1, cv2.LINE_AA)
    x = 8
    for k in ("accepted", "rejected", "not_chosen"):
        n = len(scores.get(k, []))
        cv2.rectangle(img, (x, 32), (x + 12, 44), _COLORS[k], -1)
        label = f"{_LABELS[k]} {n}"
        cv2.putText(img, label, (x + 16, 43), font, 0.4, black, 1, cv2.LINE_AA)
        x += 16 + cv2.getTextSize(label, font, 0.4, 1)[0][0] + 16
    path = Path(path)
    write_png(path, img)
    return path
