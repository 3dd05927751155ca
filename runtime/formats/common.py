"""Helpers shared by the file formats: the error type, safe JSON/npz reading and npz writing. The
writers put their folders in place with ``trioman.runtime.outputs.atomic_folder``.

Files are data: ``np.load(..., allow_pickle=False)``, never pickle. Every problem becomes a
``FormatError`` (a ValueError) whose message names the file, the field and the value.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any, Callable, Iterable, Mapping

import numpy as np

from trioman.runtime.outputs import not_a_file, write_synced


class FormatError(ValueError):
    """A file or folder does not follow its format. The message names the file, field and value."""


# --------------------------------------------------------------------------------------------------
# the subject


def format_error(where: Any, field: str | None, problem: str) -> FormatError:
    """The FormatError for ``problem`` with ``field`` of ``where`` (a file or folder)."""
    return FormatError(f"{where}: {field}: {problem}" if field else f"{where}: {problem}")


def is_int(v: Any) -> bool:
    """Whether ``v`` is a JSON integer (a bool is not)."""
    return isinstance(v, int) and not isinstance(v, bool)


def is_number(v: Any) -> bool:
    """Whether ``v`` is a finite JSON number (a bool is not)."""
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def read_json(path: str | os.PathLike, missing: str = "missing file") -> Any:
    """The one reader of a JSON file the user gives: NaN and Infinity refused, and a missing, unreadable,
    malformed or too deeply nested file (Python's parser recurses) is a FormatError naming it."""
    path = Path(path)
    require_file(path, missing)

    def reject_constant(name: str) -> Any:
        raise ValueError(f"{name} is not valid JSON")

    try:
        return json.loads(path.read_text(encoding="utf-8"), parse_constant=reject_constant)
    except (ValueError, UnicodeDecodeError) as err:
        raise FormatError(f"{path}: malformed JSON: {err}") from None
    except RecursionError:
        raise FormatError(f"{path}: malformed JSON: nested too deeply to read") from None


def require_file(path: str | os.PathLike, missing: str = "missing file") -> None:
    """FormatError naming ``path`` unless it is a regular file: ``missing`` when nothing is there, else what is
    (a folder, a FIFO or device, a broken link: ``outputs.not_a_file``)."""
    problem = not_a_file(path)
    if problem is not None:
        raise FormatError(f"{path}: {missing if problem == 'missing file' else problem}")


def load_json(path: Path) -> Any:
    """A format's metadata file through ``read_json``; a missing one asks whether this is a TrioMan folder."""
    return read_json(path, "missing file (is this a TrioMan subject folder?)")


def load_npz(path: Path, known: Iterable[str] | None = None, max_bytes: int | None = None) -> dict[str, np.ndarray]:
    """The arrays of an .npz, loaded without pickle. Any problem -> FormatError naming the file.

    ``known``: the array names the format has; another one is refused before any array is read.
    ``max_bytes``: the most an array may take once decompressed (its zip entry's size), checked before
    reading, so a small archive cannot expand into gigabytes."""
    require_file(path)
    with open(path, "rb") as f:
        head = f.read(4)
    if head == b"\x93NUM":
        raise FormatError(f"{path}: a single .npy array, not an .npz archive of named arrays")
    if head not in (b"PK\x03\x04", b"PK\x05\x06"):  # numpy would try it as a pickle and advise allow_pickle
        raise FormatError(f"{path}: not a valid .npz archive (not a zip of .npy arrays: the file starts with {head!r})")
    try:
        archive = np.load(path, allow_pickle=False)
    except Exception as err:  # a damaged zip: numpy raises several types; all mean "invalid"
        raise FormatError(f"{path}: not a valid .npz archive ({type(err).__name__}: {err})") from None
    key = None
    try:
        if known is not None:
            unknown = sorted(set(archive.files) - set(known))
            if unknown:
                raise FormatError(f"{path}: {unknown[0]}: unknown array, not read (this format has {sorted(known)})")
        if max_bytes is not None:
            for info in archive.zip.infolist():
                if info.file_size > max_bytes:
                    raise FormatError(f"{path}: {info.filename.removesuffix('.npy')}: {info.file_size} bytes once "
                                      f"decompressed, more than the {max_bytes} this file can need; not read")
        arrays = {}
        for key in archive.files:
            arrays[key] = archive[key]
        return arrays
    except FormatError:
        raise
    except ValueError as err:
        if "pickle" in str(err) or "Object arrays" in str(err):
            raise FormatError(f"{path}: {key}: holds Python objects (needs pickle), refused") from None
        raise FormatError(f"{path}: {key}: unreadable array ({err})") from None
    except Exception as err:
        raise FormatError(f"{path}: {key}: unreadable array ({type(err).__name__}: {err})") from None
    finally:
        archive.close()


def write_npz(path: Path, arrays: Mapping[str, np.ndarray]) -> None:
    """``arrays`` as an uncompressed .npz at ``path``, fsync'ed (``write_synced``)."""
    write_synced(path, lambda f: np.savez(f, **arrays))


def as_real(v: Any) -> Any:
    """A real number (numpy scalars included) as a Python float; anything else unchanged for the metadata checks."""
    if isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, (bool, np.bool_)):
        return float(v)
    return v


def plain_json(value: Any, where: str, field: str) -> Any:
    """A JSON round trip of ``value`` (numpy scalars and arrays become numbers and lists)."""

    def default(o: Any) -> Any:
        if isinstance(o, (np.generic, np.ndarray)):
            return o.tolist()
        if isinstance(o, os.PathLike):
            return os.fspath(o)
        raise TypeError(f"{type(o).__name__} is not JSON-serialisable")

    try:
        return json.loads(json.dumps(value, default=default, allow_nan=False))
    except (TypeError, ValueError) as err:
        raise FormatError(f"{where}: {field}: {err}") from None


def check_header(meta: Any, where: Any, fmt: str, version: int, kind: str) -> Callable[[str], Any]:
    """Check the fields every TrioMan JSON header shares (a JSON object; format, version, non-empty
    body_model, units "m") -> ``get(field)``, which raises FormatError for a missing field."""
    if not isinstance(meta, dict):
        raise format_error(where, None, f"expected a JSON object, got {type(meta).__name__}")
    found = meta.get("format")
    if found != fmt:
        raise format_error(where, "format", f"expected {fmt!r}, got {found!r}: not a TrioMan {kind}")
    v = meta.get("version")
    if not is_int(v):
        raise format_error(where, "version", f"expected an integer, got {v!r}")
    if v != version:
        raise format_error(where, "version", f"unknown version {v} (this trioman reads version {version})")

    def get(field: str) -> Any:
        if field not in meta:
            raise format_error(where, field, "missing field")
        return meta[field]

    body_model = get("body_model")
    if not isinstance(body_model, str) or not body_model:
        raise format_error(where, "body_model", f"expected a non-empty string, got {body_model!r}")
    if get("units") != "m":
        raise format_error(where, "units", f"expected 'm' (metres), got {meta['units']!r}")
    return get
