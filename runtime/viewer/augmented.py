"""An augment output in the viewer (``trioman view --augmented DIR``, docs/formats.md "Augmented frames").

Per source frame (picked from its records): the real source frame, each Generator candidate's coarse
render, the refined frame that was kept, the Examiner's scores and each candidate's status, and the
candidates' cameras as frustums. Only kept frames are written by augment, so the coarse renders are
drawn again: the record's frame seed and the run's Generator settings give the same candidates, rendered
by the run's avatar (numpy splat renderer) as augment rendered them.
"""

from __future__ import annotations

import math
import os
from dataclasses import fields
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from trioman.runtime.augment import AUGMENT_JSON, RECORDS_DIR
from trioman.runtime.formats import FormatError, load_avatar, load_subject
from trioman.runtime.formats.common import is_int, read_json
from trioman.runtime.formats.subject import IMAGES_DIR, check_frame_name
from trioman.runtime.generator import GeneratorConfig, sample
from trioman.runtime.image_io import read_png
from trioman.runtime.preview import contact_sheet
from trioman.runtime.render import rasterize
from trioman.runtime.viewer.cameras import FRUSTUM_SCALE, frustum_pose

SHEET_SIDE = 192  # pixels, the longer side of each image of the sheet
_KEPT, _OTHER = (30, 160, 60), (150, 150, 150)


def read_run(path: str | os.PathLike) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """augment.json and the records (source frame order) of an augment output folder, checked: a problem is a
    FormatError naming the file and the field (docs/design.md, "What a command may delete, and what it may
    read": names from records are frame names)."""
    root = Path(path)
    if not root.is_dir():
        raise FormatError(f"{root}: augment output folder not found")
    meta_path = root / AUGMENT_JSON
    meta = read_json(meta_path, f"missing file (is {root} a trioman augment output?)")
    settings = _check_settings(meta, meta_path)
    records = []
    inside = root.resolve() / RECORDS_DIR
    for record_path in sorted((root / RECORDS_DIR).glob("*.json")):
        if inside not in record_path.resolve().parents:
            raise FormatError(f"{record_path}: a link that leads outside {inside}; an augment output holds no links")
        records.append(_check_record(read_json(record_path), record_path, settings["per_frame"]))
    if not records:
        raise FormatError(f"{root / RECORDS_DIR}: no records (the run finished no source frame)")
    records.sort(key=lambda r: r["source"]["index"])
    summary = meta.get("summary", {})
    return {"settings": settings, "summary": summary if isinstance(summary, dict) else {}}, records


def _check_settings(meta: Any, where: Path) -> dict[str, Any]:
    """augment.json's settings: the subject and avatar paths, per_frame and the Generator's settings."""
    settings = meta.get("settings") if isinstance(meta, dict) else None
    if not isinstance(settings, dict):
        raise FormatError(f"{where}: settings: missing or not an object")
    for key in ("subject", "avatar"):
        if not (isinstance(settings.get(key), dict) and isinstance(settings[key].get("path"), str)):
            raise FormatError(f"{where}: settings.{key}.path: missing or not a string")
    per_frame = settings.get("per_frame")
    if not (is_int(per_frame) and per_frame >= 1):
        raise FormatError(f"{where}: settings.per_frame: expected an integer >= 1, got {per_frame!r}")
    generator = settings.get("generator")
    if not isinstance(generator, dict):
        raise FormatError(f"{where}: settings.generator: missing or not an object")
    known = {f.name for f in fields(GeneratorConfig)}
    unknown = sorted(set(generator) - known)
    if unknown:
        raise FormatError(f"{where}: settings.generator: unknown key {unknown[0]!r} (known: {', '.join(sorted(known))})")
    try:
        GeneratorConfig(**generator)
    except (ValueError, TypeError) as err:
        raise FormatError(f"{where}: settings.generator: {err}") from None
    return settings


def _check_record(record: Any, where: Path, per_frame: int) -> dict[str, Any]:
    """One record: its source frame, seed, per_frame candidates and the frames it kept, whose names are frame
    names (``check_frame_name``), so they stay file names inside images/."""
    def fail(field: str, problem: str) -> FormatError:
        return FormatError(f"{where}: {field}: {problem}")

    if not isinstance(record, dict):
        raise fail("record", "not an object")
    source = record.get("source")
    if not (isinstance(source, dict) and is_int(source.get("index")) and source["index"] >= 0):
        raise fail("source.index", f"expected an integer >= 0, got {source.get('index') if isinstance(source, dict) else source!r}")
    check_frame_name(source.get("name"), where, "source.name")
    if not (is_int(record.get("seed")) and record["seed"] >= 0):
        raise fail("seed", f"expected an integer >= 0, got {record.get('seed')!r}")
    candidates = record.get("candidates")
    if not (isinstance(candidates, list) and len(candidates) == per_frame):
        got = f"{len(candidates)}" if isinstance(candidates, list) else repr(candidates)
        raise fail("candidates", f"expected a list of settings.per_frame = {per_frame} candidates, got {got}")
    for k, c in enumerate(candidates):
        ok = (isinstance(c, dict) and is_int(c.get("candidate")) and isinstance(c.get("status"), str)
              and (c.get("score") is None or (isinstance(c["score"], (int, float)) and not isinstance(c["score"], bool)
                                              and math.isfinite(c["score"]))))
        if not ok:
            raise fail(f"candidates[{k}]", f"expected candidate (int), status (str) and score (number or null), got {c!r}")
        if c.get("frame") is not None:
            check_frame_name(c["frame"], where, f"candidates[{k}].frame")
    frames = record.get("frames")
    if not isinstance(frames, list):
        raise fail("frames", f"expected a list, got {frames!r}")
    for k, f in enumerate(frames):
        if not (isinstance(f, dict) and is_int(f.get("candidate"))):
            raise fail(f"frames[{k}]", f"expected name (str) and candidate (int), got {f!r}")
        check_frame_name(f.get("name"), where, f"frames[{k}].name")
    chosen = record.get("chosen")
    if not (chosen is None or is_int(chosen)):
        raise fail("chosen", f"expected an integer or null, got {chosen!r}")
    return record


def frame_path(root: str | os.PathLike, name: str, where: Any = None) -> Path:
    """``root/images/<name>.png`` for a frame name from a record, checked: the name is a frame name and the
    path, links resolved, lies inside ``root/images`` (FormatError naming ``where`` otherwise)."""
    images = Path(root) / IMAGES_DIR
    check_frame_name(name, where or images, "frame name")
    path = images / f"{name}.png"
    if Path(root).resolve() / IMAGES_DIR not in path.resolve().parents:  # images/ itself may not be a link either
        raise FormatError(f"{where or images}: frame {name!r}: its file is a link that leads outside {images}")
    return path


def run_avatar_path(path: str | os.PathLike) -> Path:
    """The avatar an augment run used (``settings.avatar.path`` of its augment.json)."""
    return Path(read_run(path)[0]["settings"]["avatar"]["path"])


def _fit(img: np.ndarray, w: int, h: int) -> np.ndarray:
    return img if img.shape[:2] == (h, w) else cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA)


class AugmentedView:
    """The augment output ``path`` on ``viewer`` (an ``AvatarViewer``), one source frame at a time."""

    def __init__(self, viewer, path: str | os.PathLike):
        self.viewer = viewer
        self.root = Path(path)
        meta, self.records = read_run(path)
        settings = meta["settings"]
        for key in ("subject", "avatar"):
            if not Path(settings[key]["path"]).is_dir():
                raise FormatError(f"{self.root / AUGMENT_JSON}: settings.{key}.path: {settings[key]['path']} not found "
                                  f"(the run's {key} moved?)")
        self.subject = load_subject(settings["subject"]["path"], check_images=False)
        for record in self.records:
            i, name = record["source"]["index"], record["source"]["name"]
            if i >= self.subject.num_frames or self.subject.frame_names[i] != name:
                raise FormatError(f"{self._record_path(record)}: source: frame {i} {name!r} is not a frame of the "
                                  f"subject {self.subject.root} ({self.subject.num_frames} frames)")
        same = viewer.poser.avatar.root is not None and \
            Path(viewer.poser.avatar.root).resolve() == Path(settings["avatar"]["path"]).resolve()
        self.avatar = viewer.poser.avatar if same else load_avatar(settings["avatar"]["path"])
        self.generator = GeneratorConfig(**settings["generator"])  # checked by read_run
        self.per_frame = settings["per_frame"]
        self._frustums: list[Any] = []
        names = tuple(r["source"]["name"] for r in self.records)
        gui = viewer.server.gui
        with gui.add_folder("Augmented"):
            gui.add_markdown(_summary(meta["summary"], self.root))
            self._pick = gui.add_dropdown("source frame", names, initial_value=names[0])
            self._table = gui.add_markdown("")
            self._sheet = gui.add_image(np.ones((8, 16, 3), np.uint8), label="source | candidates (coarse) | refined")
        self._pick.on_update(lambda _event: self.show(self._pick.value))
        self.show(names[0])

    def images(self, record: dict[str, Any]) -> tuple[list[np.ndarray], list[str]]:
        """The sheet of one record: source, each candidate's coarse render, the kept refined frame(s), with labels."""
        s, i = self.subject, int(record["source"]["index"])
        scale = min(1.0, SHEET_SIDE / max(s.width, s.height))
        w, h = max(1, round(s.width * scale)), max(1, round(s.height * scale))
        cands = self.candidates(record)
        K = np.array(s.K[i], dtype=np.float64)
        K[:2] *= np.array([[w / s.width], [h / s.height]])
        images, labels = [_fit(s.image(i), w, h)], [f"source {record['source']['name']}"]
        for c, info in zip(cands, record["candidates"]):
            r = rasterize(*self.avatar.gaussians(c.pose, c.trans), c.viewmat, K, w, h, background=s.background)
            score = "" if info["score"] is None else f" {info['score']:.3f}"
            images.append(np.clip(r.rgb, 0.0, 1.0))
            labels.append(f"c{info['candidate']}{score} {info['status']}")
        for f in record["frames"]:
            images.append(_fit(read_png(frame_path(self.root, f["name"], self._record_path(record)), mode="rgb"), w, h))
            labels.append(f"refined c{f['candidate']} (kept)")
        return images, labels

    def _record_path(self, record: dict[str, Any]) -> Path:
        return self.root / RECORDS_DIR / f"{record['source']['name']}.json"

    def candidates(self, record: dict[str, Any]) -> list:
        """The Generator's candidates of a record, drawn again from its frame seed."""
        s, i = self.subject, int(record["source"]["index"])
        return sample(s.body.skeleton, s.poses[i], s.trans[i], s.viewmat[i], record["seed"], self.per_frame,
                      self.generator)

    def show(self, name: str) -> np.ndarray:
        """Show source frame ``name``. -> the sheet [H, W, 3] float32."""
        record = next(r for r in self.records if r["source"]["name"] == name)
        images, labels = self.images(record)
        sheet = contact_sheet(images, labels, cols=len(images))
        self._sheet.image = (sheet * 255).round().astype(np.uint8)
        self._table.content = _table(record)
        for handle in self._frustums:
            handle.remove()
        s, i = self.subject, int(record["source"]["index"])
        kept = {f["candidate"] for f in record["frames"]}
        self._frustums = []
        for c, info in zip(self.candidates(record), record["candidates"]):
            wxyz, position = frustum_pose(c.viewmat)
            self._frustums.append(self.viewer.server.scene.add_camera_frustum(
                f"/augmented/c{info['candidate']}", fov=float(2 * np.arctan(0.5 * s.height / s.K[i][1, 1])),
                aspect=s.width / s.height, scale=FRUSTUM_SCALE, wxyz=wxyz, position=position,
                color=_KEPT if info["candidate"] in kept else _OTHER))
        return sheet


def _table(record: dict[str, Any]) -> str:
    rows = ["| candidate | Examiner score | status | written frame |", "|---|---|---|---|"]
    for c in record["candidates"]:
        score = "-" if c["score"] is None else f"{c['score']:.3f}"
        rows.append(f"| c{c['candidate']} | {score} | {c['status']} | {c['frame'] or '-'} |")
    chosen = record["chosen"]
    head = (f"**{record['source']['name']}**: Examiner chose " + ("none (no Examiner)" if chosen is None else f"c{chosen}")
            + ("" if record["kept"] else ", below the threshold: nothing kept"))
    return head + "\n\n" + "\n".join(rows)


def _summary(summary: dict[str, Any], root: Path) -> str:
    if not summary:
        return f"augment output {root.name} (unfinished: no summary)"
    return (f"augment output **{root.name}**: {summary.get('source_frames')} source frames, "
            f"{summary.get('candidates')} candidates, {summary.get('frames_written', 0)} frames written")
