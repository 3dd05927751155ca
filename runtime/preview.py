"""Pictures for people: contact sheets of labelled frames."""

from __future__ import annotations

from typing import Sequence

import cv2
import numpy as np


def contact_sheet(images: Sequence[np.ndarray], labels: Sequence[str] | None = None, cols: int = 6,
                  pad: int = 4, background: float = 1.0) -> np.ndarray:
    """Tile float32 RGB images [H, W, 3] (same size) into one sheet with a caption under each.

    -> [rows * (H + caption + pad) + pad, cols * (W + pad) + pad, 3] float32.
    """
    if len(images) == 0:
        raise ValueError("images: need at least one image for a contact sheet")
    H, W = images[0].shape[:2]
    for k, img in enumerate(images):
        if img.shape != (H, W, 3):
            raise ValueError(f"images[{k}]: expected shape {[H, W, 3]}, got {list(img.shape)}")
    labels = list(labels) if labels is not None else [""] * len(images)
    if len(labels) != len(images):
        raise ValueError(f"labels: {len(labels)} labels for {len(images)} images")
    cols = max(1, min(cols, len(images)))
    rows = -(-len(images) // cols)
    cap = 16 if any(labels) else 0
    sheet = np.full((rows * (H + cap + pad) + pad, cols * (W + pad) + pad, 3), background, np.float32)
    for k, (img, text) in enumerate(zip(images, labels)):
        r, c = divmod(k, cols)
        y, x = pad + r * (H + cap + pad), pad + c * (W + pad)
        sheet[y : y + H, x : x + W] = img
        if text:
            tile = np.ascontiguousarray((sheet[y + H : y + H + cap, x : x + W] * 255).round().astype(np.uint8))
            cv2.putText(tile, text, (2, cap - 4), cv2.FONT_HERSHEY_SIMPLEX, 0.38, (25, 25, 25), 1, cv2.LINE_AA)
            sheet[y + H : y + H + cap, x : x + W] = tile.astype(np.float32) / 255
    return sheet
