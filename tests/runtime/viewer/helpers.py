"""Tiny inputs of the viewer tests, built without torch: an avatar on the 3-joint chain of
tests/runtime/factories.py, a subject on that body, and an augment output that names both."""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

import numpy as np

from tests.runtime.factories import make_fields
from trioman.runtime.augment import frame_seed
from trioman.runtime.formats import load_subject, save_avatar, save_subject
from trioman.runtime.generator import GeneratorConfig, sample
from trioman.runtime.image_io import write_png

N_GAUSSIANS = 600


def make_avatar(path: Path, n: int = N_GAUSSIANS, seed: int = 0):
    """A coloured column around the chain (z 0.85..1.55 m, 0.24 m wide), skinned to its nearest joints."""
    body = make_fields()["body"]
    rng = np.random.default_rng(seed)
    z = rng.uniform(0.85, 1.55, n)
    positions = np.stack([rng.uniform(-0.12, 0.12, n), rng.uniform(-0.03, 0.03, n), z], 1).astype(np.float32)
    d = np.abs(z[:, None] - body.skeleton.joints[None, :, 2])  # [n, 3]
    idx = np.argsort(d, axis=1)[:, :2].astype(np.int32)
    w = 1.0 / (np.take_along_axis(d, idx, 1) + 1e-3)
    t = (z - 0.85) / 0.7  # red at the bottom, blue at the top
    rgb = np.stack([1 - t, 0.3 * np.ones(n), t], 1)
    return save_avatar(path, skeleton=body.skeleton, body_model="test-chain", gaussians={
        "positions": positions,
        "log_scales": np.full((n, 1), np.log(0.03), np.float32),
        "rgb_logits": np.log(np.clip(rgb, 0.05, 0.95) / (1 - np.clip(rgb, 0.05, 0.95))).astype(np.float32),
        "opacities": np.full(n, 0.9, np.float32),
        "skin_indices": idx, "skin_weights": (w / w.sum(1, keepdims=True)).astype(np.float32),
    })


def make_subject(path: Path) -> Path:
    fields = make_fields()
    n, H, W = len(fields["poses"]), fields["height"], fields["width"]
    rng = np.random.default_rng(1)
    save_subject(path, images=[rng.random((H, W, 3), dtype=np.float32) for _ in range(n)],
                 masks=[np.ones((H, W), np.float32)] * n, **fields)
    return path


def make_augment_output(path: Path, subject: Path, avatar: Path, per_frame: int = 2) -> Path:
    """augment.json, one record per train frame (candidate 1 kept) and the kept frames' images, as augment writes them."""
    s = load_subject(subject)
    cfg = GeneratorConfig()
    records = []
    (path / "records").mkdir(parents=True)
    (path / "images").mkdir()
    for i in s.indices("train"):
        name = str(s.frame_names[i])
        seed = frame_seed(0, int(i))
        cands = sample(s.body.skeleton, s.poses[i], s.trans[i], s.viewmat[i], seed, per_frame, cfg)
        write_png(path / "images" / f"{name}_c1.png", np.full((s.height, s.width, 3), 0.5, np.float32))
        records.append({
            "version": 1, "source": {"index": int(i), "name": name, "sequence": str(s.sequence[i])}, "seed": seed,
            "chosen": 1, "kept": True,
            "candidates": [{"candidate": k, "status": "accepted" if k == 1 else "not_chosen", "score": 0.2 + 0.5 * k,
                            "frame": f"{name}_c1" if k == 1 else None} for k in range(per_frame)],
            "frames": [{"name": f"{name}_c1", "candidate": 1, "pose": cands[1].pose.tolist()}],
        })
        (path / "records" / f"{name}.json").write_text(json.dumps(records[-1]))
    settings = {"subject": {"path": str(subject.resolve())}, "avatar": {"path": str(avatar.resolve())},
                "per_frame": per_frame, "generator": asdict(cfg)}
    summary = {"source_frames": len(records), "candidates": per_frame * len(records), "frames_written": len(records)}
    (path / "augment.json").write_text(json.dumps({"format": "trioman-augment", "settings": settings, "summary": summary}))
    return path
