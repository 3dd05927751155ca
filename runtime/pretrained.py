"""The Refiner and the Examiner that ship inside the package (``runtime/pretrained/``; their model card:
docs/models.md): what ``trioman train --augment`` and ``trioman augment`` use when no model is given.

A model option takes a path, ``shipped`` (the default: the file here, checked against its recorded sha256) or
``none`` (no model). ``models.json`` records each file's name, bytes, sha256, input size and parity, and how
the models were made; ``trioman export pretrained`` writes it (export/pretrained.py). Standard-library imports
at module level: the commands' options read ``SHIPPED`` and ``NONE``.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

PRETRAINED_DIR = Path(__file__).with_name("pretrained")
RECORD = "models.json"
FORMAT = "trioman-pretrained"
FORMAT_VERSION = 1
KINDS = ("refiner", "examiner")
SHIPPED = "shipped"  # a model option's value: the model shipped here
NONE = "none"  # a model option's value: no model


def read_record(folder: Path | None = None) -> dict[str, Any]:
    """``folder/models.json`` (default PRETRAINED_DIR), checked: its format and, per kind, a file name inside
    ``folder``, bytes and sha256."""
    from trioman.runtime.formats.common import FormatError, is_int, read_json

    folder = PRETRAINED_DIR if folder is None else folder
    path = folder / RECORD
    record = read_json(path, missing="missing file (this install carries no shipped models; give a model's path)")
    if not isinstance(record, dict) or record.get("format") != FORMAT or record.get("format_version") != FORMAT_VERSION:
        raise FormatError(f"{path}: format: expected {FORMAT!r} version {FORMAT_VERSION}, got "
                          f"{record.get('format') if isinstance(record, dict) else type(record).__name__!r}")
    models = record.get("models")
    if not isinstance(models, dict):
        raise FormatError(f"{path}: models: expected an object keyed by kind, got {type(models).__name__}")
    for kind, entry in models.items():
        if kind not in KINDS or not isinstance(entry, dict):
            raise FormatError(f"{path}: models.{kind}: expected one of {KINDS} with an object, got {kind!r}")
        name = entry.get("file")
        if not isinstance(name, str) or not name.endswith(".onnx") or Path(name).name != name:
            raise FormatError(f"{path}: models.{kind}.file: expected a file name in this folder, got {name!r}")
        sha = entry.get("sha256")
        if not isinstance(sha, str) or len(sha) != 64:
            raise FormatError(f"{path}: models.{kind}.sha256: expected 64 hex digits, got {sha!r}")
        if not is_int(entry.get("bytes")) or entry["bytes"] < 1:
            raise FormatError(f"{path}: models.{kind}.bytes: expected a positive integer, got {entry.get('bytes')!r}")
    return record


def shipped_path(kind: str, folder: Path | None = None) -> Path:
    """The shipped ``kind`` model's file in ``folder`` (default PRETRAINED_DIR), after checking its size and sha256
    against ``models.json``."""
    from trioman.runtime.formats.avatar import sha256_file
    from trioman.runtime.formats.common import FormatError

    if kind not in KINDS:
        raise ValueError(f"kind: expected one of {KINDS}, got {kind!r}")
    folder = PRETRAINED_DIR if folder is None else folder
    record = read_record(folder)
    entry = record["models"].get(kind)
    if entry is None:
        raise FormatError(f"{folder / RECORD}: models: no shipped {kind} (give a model's path)")
    path = folder / entry["file"]
    if not path.is_file():
        raise FormatError(f"{path}: missing file (the shipped {kind} named by {folder / RECORD}); reinstall trioman "
                          f"or give a model's path")
    size = path.stat().st_size
    if size != entry["bytes"] or sha256_file(path) != entry["sha256"]:
        raise FormatError(f"{path}: not the shipped {kind} recorded in {folder / RECORD} (bytes {size}, expected "
                          f"{entry['bytes']}; or its sha256 differs); reinstall trioman or give a model's path")
    return path


def resolve_model(value: str | os.PathLike | None, kind: str) -> Path | None:
    """A model option's value -> the file or folder to load, or None: ``shipped`` -> the shipped file (a missing
    or altered one: a ValueError naming ``kind``, the option), ``none`` and None -> None, anything else -> that
    path (checked by its loader)."""
    if value is None or str(value) == NONE:
        return None
    if str(value) == SHIPPED:
        try:
            return shipped_path(kind)
        except ValueError as err:
            raise ValueError(f"{kind}: the shipped {kind}: {err}") from None
    return Path(value)
