"""Where a command may write, and how: the atomic writes of every module and the folder rule.

Every write goes to a temporary file in the destination folder, is fsync'ed and renamed into place, so a
reader never sees a half-written file and an interrupted write leaves nothing behind: one file with
``atomic_path`` (and ``atomic_write_bytes``/``atomic_write_text``), a folder of files with ``atomic_folder``,
whose files are written with ``write_synced``. The one rule of every command that writes a folder or a file
(docs/design.md, "What a command may delete, and what it may read") lives here: ``check_folder_target``,
``check_not_input``, the kinds of folder trioman writes (``FolderKind``, ``known_kind``, ``kind_of``) and
``remove_own``.
"""

from __future__ import annotations

import contextlib
import errno
import fnmatch
import json
import os
import re
import secrets
import shutil
import socket
import time
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO, Callable, Iterable, Iterator

PathLike = str | os.PathLike


def fsync_dir(path: PathLike) -> None:
    """fsync a folder so a rename inside it is durable (no-op where folders cannot be opened)."""
    try:
        fd = os.open(os.fspath(path), os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def fsync_file(path: PathLike) -> None:
    """fsync a written file (one written by a library that does not, before it is renamed into place)."""
    fd = os.open(os.fspath(path), os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def temp_sibling(path: Path, suffix: str = "") -> Path:
    """A fresh hidden name next to ``path`` (``.NAME.XXXXXXXX.tmpSUFFIX``); nothing is created."""
    return path.with_name(f".{path.name}.{secrets.token_hex(4)}.tmp{suffix}")


# The one pattern of every temporary name (temp_sibling): what a kill -9 may leave behind.
_TEMP_NAME = re.compile(r"\..+\.[0-9a-f]{8}\.tmp(\.[A-Za-z0-9]+)?")


def is_temp_name(name: str) -> bool:
    """Whether ``name`` is a temporary file or folder name made by :func:`temp_sibling`."""
    return _TEMP_NAME.fullmatch(name) is not None


def remove_temp_files(folder: PathLike) -> list[Path]:
    """Remove the temporary files and folders (:func:`is_temp_name`) under ``folder``, at any depth, that an
    interrupted write left behind; nothing else. -> what was removed."""
    removed = []
    for root, dirs, files in os.walk(folder):
        for name in [d for d in dirs if is_temp_name(d)]:
            shutil.rmtree(Path(root) / name)
            dirs.remove(name)
            removed.append(Path(root) / name)
        for name in files:
            if is_temp_name(name):
                (Path(root) / name).unlink()
                removed.append(Path(root) / name)
    return sorted(removed)


def _create_temp(path: Path, suffix: str) -> Path:
    # Created like open() would (mode 0o666 minus the umask), unlike tempfile.mkstemp's 0o600.
    for _ in range(100):
        tmp = temp_sibling(path, suffix)
        try:
            os.close(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
            return tmp
        except FileExistsError:
            continue
        except OSError as err:  # a read-only, full or foreign folder: name the file being written
            raise OSError(err.errno, err.strerror, str(path)) from err
    raise FileExistsError(f"{path}: could not create a temporary file next to it")


@contextlib.contextmanager
def naming_os_errors(path: PathLike, *aliases: PathLike) -> Iterator[None]:
    """Re-raise an OSError of the block that names no file (a write to an open file: disk full), or
    names one of ``aliases`` (a temporary file), as the same error naming ``path``."""
    try:
        yield
    except OSError as err:
        names = {None, *(os.fspath(a) for a in aliases)}
        if err.errno is None or err.filename not in names:
            raise
        raise OSError(err.errno, err.strerror, os.fspath(path)) from err


@contextlib.contextmanager
def atomic_path(path: PathLike, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; on success fsync it and ``os.replace`` it onto ``path``.

    ``suffix`` is the temporary name's ending (default: ``path``'s own suffix, so tools that pick a
    format from the extension, such as OpenCV's VideoWriter, still work). If the block raises, the
    temporary file is removed and ``path`` is left untouched. An OSError about the temporary file
    (disk full, permission, read-only file system) names ``path``; a folder at ``path`` is refused first.
    """
    path = Path(path)
    if not path.parent.is_dir():
        raise FileNotFoundError(f"{path}: the folder {path.parent} does not exist")
    if path.is_dir():
        raise IsADirectoryError(errno.EISDIR, os.strerror(errno.EISDIR), str(path))
    tmp_path = _create_temp(path, path.suffix if suffix is None else suffix)
    try:
        with naming_os_errors(path, tmp_path):
            yield tmp_path
            fsync_file(tmp_path)
            os.replace(tmp_path, path)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp_path.unlink()
        raise
    fsync_dir(path.parent)


def atomic_write_bytes(path: PathLike, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically."""
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            f.write(data)


def atomic_write_text(path: PathLike, text: str) -> None:
    """Write UTF-8 ``text`` to ``path`` atomically."""
    atomic_write_bytes(path, text.encode("utf-8"))


def write_synced(path: PathLike, data: bytes | Callable[[BinaryIO], None]) -> None:
    """Write the file ``path`` (``data``: its bytes, or a function that writes into the open file) and fsync
    it; an OSError names ``path``. For the files of an :func:`atomic_folder`; a file alone is written with
    :func:`atomic_path`."""
    with naming_os_errors(path), open(path, "wb") as f:
        if callable(data):
            data(f)
        else:
            f.write(data)
        f.flush()
        os.fsync(f.fileno())


@dataclass(frozen=True)
class FolderKind:
    """One kind of folder a command writes (a subject, an avatar, ...): what ``overwrite`` may replace.

    ``marker``: the metadata file (or sub-folder) that makes a folder this kind; ``files``: the patterns (fnmatch) of the
    files it holds at the top (the marker included); ``folders``: each sub-folder's name (a pattern) -> the
    patterns of the files in it. Temporary names (:func:`is_temp_name`) belong to every kind (what a kill -9 left).
    Anything else is foreign: a folder holding it is never replaced."""

    name: str  # in messages: "a trioman <name> folder"
    marker: str
    files: tuple[str, ...] = ()
    folders: tuple[tuple[str, tuple[str, ...]], ...] = ()
    format: str | None = None  # the marker's JSON "format": what tells trioman's marker from another program's file

    def first_foreign(self, path: PathLike) -> Path | None:
        """The first entry of the folder ``path`` (sorted, top level first) that this kind does not write: its
        first entry when the marker is missing. None when the folder is this kind's and holds nothing else."""
        path = Path(path)
        entries = sorted(path.iterdir(), key=lambda p: p.name)
        if not (path / self.marker).exists():
            return next((p for p in entries if not is_temp_name(p.name)), None)
        for entry in entries:
            name = entry.name
            if is_temp_name(name):
                continue
            inside = next((patterns for folder, patterns in self.folders if fnmatch.fnmatchcase(name, folder)), None)
            if inside is not None and entry.is_dir() and not entry.is_symlink():
                for inner in sorted(entry.iterdir(), key=lambda p: p.name):
                    if not (is_temp_name(inner.name) or (inner.is_file() and not inner.is_symlink()
                                                         and _matches(inner.name, inside))):
                        return inner
            elif not (entry.is_file() and not entry.is_symlink() and _matches(name, self.files)):
                return entry
        return None


def _matches(name: str, patterns: Iterable[str]) -> bool:
    return any(fnmatch.fnmatchcase(name, pattern) for pattern in patterns)


_KNOWN: dict[str, FolderKind] = {}  # marker -> the kind of folder trioman writes with it (``known_kind``)


def known_kind(kind: FolderKind) -> FolderKind:
    """Declare ``kind`` as a folder trioman writes (its module does, where the kind is defined): no output goes
    inside such a folder, and a refusal names the kind a folder is (:func:`kind_of`). -> ``kind``"""
    _KNOWN[kind.marker] = kind
    return kind


def _marks(path: Path, kind: FolderKind) -> bool:
    """Whether ``path`` holds ``kind``'s marker (a JSON object of its ``format``, when the kind has one)."""
    marker = path / kind.marker
    if not marker.is_file():
        return False
    if kind.format is None:
        return True
    try:
        with open(marker, "rb") as f:
            head = json.loads(f.read(1 << 20))  # a marker is small; a larger file is not one of ours
    except (OSError, ValueError):
        return False
    return isinstance(head, dict) and head.get("format") == kind.format


def kind_of(path: PathLike) -> FolderKind | None:
    """The declared kind whose marker the folder ``path`` holds (None: none, or not a folder)."""
    path = Path(path)
    return next((k for k in _KNOWN.values() if _marks(path, k)), None)


def _enclosing(target: Path) -> tuple[Path, FolderKind] | None:
    """The nearest folder above the resolved ``target`` that is a folder of a declared kind."""
    for parent in target.parents:
        kind = kind_of(parent)
        if kind is not None:
            return parent, kind
    return None


def not_a_file(path: PathLike) -> str | None:
    """None when ``path`` is a regular file (through links); else what it is instead, for an error message:
    "missing file", "a broken link", "a folder, not a file" or "not a regular file (a FIFO, socket or device)"."""
    path = Path(path)
    if path.is_file():
        return None
    if path.is_dir():
        return "a folder, not a file"
    if path.exists():
        return "not a regular file (a FIFO, socket or device)"
    return "a broken link" if path.is_symlink() else "missing file"


def check_not_input(path: PathLike, inputs: Iterable[PathLike | None]) -> None:
    """ValueError when the output ``path`` (a folder or a file) is one of ``inputs``, holds one, or lies inside
    one, or lies inside a folder of a kind trioman writes (a subject, an avatar, ...: :func:`known_kind`): a
    command never writes over or into what it reads, nor into another output (None entries are skipped). Links
    are resolved first."""
    target = Path(path).resolve()
    for given in inputs:
        if given is None:
            continue
        source = Path(given).resolve()
        if target == source:
            raise ValueError(f"{path}: is the input {given}; write the output to another folder")
        if target in source.parents:
            raise ValueError(f"{path}: holds the input {given}; write the output to another folder")
        if source in target.parents:
            raise ValueError(f"{path}: lies inside the input {given}; write the output outside it")
    inside = _enclosing(target)
    if inside is not None:
        folder, kind = inside
        raise ValueError(f"{path}: lies inside {folder}, a trioman {kind.name} folder; write the output outside it")


def check_folder_target(path: PathLike, overwrite: bool, kind: FolderKind | None = None,
                        inputs: Iterable[PathLike | None] = ()) -> None:
    """The one rule of every command that writes a folder (``overwrite``, the commands' ``--overwrite``;
    docs/design.md, "What a command may delete, and what it may read").

    A new folder may take ``path`` when nothing is there or an empty folder; a non-empty folder is replaced
    only with ``overwrite`` and only when it is a folder of ``kind`` holding nothing but what that kind
    writes (without ``kind``: never). Otherwise a FileExistsError names the first foreign file. ``path``
    may not be, hold or lie inside one of ``inputs`` (ValueError, :func:`check_not_input`)."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise FileExistsError(f"{path}: exists and is not a folder")
    check_not_input(path, inputs)
    if not path.is_dir() or not any(path.iterdir()):
        return
    if kind is None:
        other = kind_of(path)
        what = f" (a trioman {other.name} folder)" if other is not None else ""
        raise FileExistsError(f"{path}: folder exists and is not empty{what} (choose another output folder)")
    foreign = kind.first_foreign(path)
    if foreign is None:
        if not overwrite:
            raise FileExistsError(f"{path}: folder exists and is not empty (give `overwrite` to replace it)")
        return
    other = kind_of(path)
    if other is not None and other is not kind:
        why = f"it is a trioman {other.name} folder ({other.marker}), not a {kind.name} folder"
        raise FileExistsError(f"{path}: {why}; refusing to replace it (choose another output folder)")
    why = (f"the folder holds no {kind.marker}: not a trioman {kind.name} folder" if not (path / kind.marker).exists()
           else f"not part of a trioman {kind.name} folder")
    if overwrite:
        raise FileExistsError(f"overwrite: {foreign} was not written by trioman ({why}); refusing to replace {path} "
                              f"(move it away, or choose another output folder)")
    raise FileExistsError(f"{path}: folder exists and holds {foreign}, which trioman did not write ({why}); choose "
                          f"another output folder")


def remove_own(path: PathLike, kind: FolderKind) -> None:
    """Remove the folder ``path`` when it is an earlier output of ``kind`` holding nothing else (what
    ``overwrite`` may replace, :func:`check_folder_target`; a FileExistsError names anything foreign); nothing
    there: nothing to do. For a command that always starts a fresh output in a fixed sub-folder of its own."""
    path = Path(path)
    if path.is_symlink():
        raise FileExistsError(f"{path}: is a link, which trioman never writes there; refusing to remove it")
    if not path.exists():
        return
    check_folder_target(path, True, kind)
    shutil.rmtree(path)


@contextlib.contextmanager
def atomic_folder(path: PathLike, overwrite: bool = False, kind: FolderKind | None = None,
                  inputs: Iterable[PathLike | None] = ()) -> Iterator[Path]:
    """Yield a new temporary folder next to ``path`` (its parents created); on success fsync every folder in
    it and rename it onto ``path``, whose old folder (:func:`check_folder_target` with ``overwrite``, ``kind``
    and ``inputs``, checked before and at the rename) is removed once the new one is in place. If the block
    raises, the temporary folder is removed and ``path`` is left untouched. Its files are written with
    :func:`write_synced` (or fsync'ed)."""
    path, inputs = Path(path), tuple(inputs)
    check_folder_target(path, overwrite, kind, inputs)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = temp_sibling(path)
    os.mkdir(tmp)
    try:
        yield tmp
        for folder, _, _ in os.walk(tmp, topdown=False):
            fsync_dir(folder)
        check_folder_target(path, overwrite, kind, inputs)  # a folder may have appeared while the block wrote
        old = None
        if path.is_dir():
            if any(path.iterdir()):
                old = temp_sibling(path, ".old")
                os.rename(path, old)
            else:
                path.rmdir()
        try:
            os.rename(tmp, path)
        except BaseException:
            if old is not None:
                os.rename(old, path)
            raise
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    fsync_dir(path.parent)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)
    stale = re.compile(re.escape(f".{path.name}.") + r"[0-9a-f]{8}\.tmp")
    for left in path.parent.iterdir():  # what an interrupted (kill -9) write of this same output left behind
        if stale.fullmatch(left.name) and left.is_dir() and not left.is_symlink():
            shutil.rmtree(left, ignore_errors=True)


def _lock(path: Path, what: str) -> None:
    """Create the lock file ``path`` exclusively (one writer at a time, on every machine sharing the folder), or
    refuse: ``what`` starts the message (``shard 0/2: another job of this shard``)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
    except FileExistsError:
        try:
            holder = json.loads(path.read_text(encoding="utf-8"))
            who = f"pid {holder['pid']} on {holder['host']} since {time.strftime('%Y-%m-%d %H:%M:%S', time.localtime(holder['started']))}"
            gone = holder["host"] == socket.gethostname() and not _alive(int(holder["pid"]))
        except (OSError, ValueError, KeyError, TypeError):
            who, gone = "being started", False
        state = "was killed (that process is gone)" if gone else "is running"
        raise ValueError(f"{what} {state} ({who}; lock {path}); "
                         + (f"remove {path} and run it again" if gone else
                            f"wait for it, or if it was killed, remove {path} and run it again")) from None
    with os.fdopen(fd, "w", encoding="utf-8") as f:
        f.write(json.dumps({"host": socket.gethostname(), "pid": os.getpid(), "started": time.time()}) + "\n")


@contextlib.contextmanager
def writer_lock(path: Path, what: str) -> Iterator[None]:
    """Hold the lock file ``path`` while the block runs (``_lock``; ``what`` names the writer in a refusal)."""
    _lock(path, what)
    try:
        yield
    finally:
        path.unlink(missing_ok=True)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # another user's process
        return True
    return True


@contextlib.contextmanager
def process_lock(path: Path, what: str) -> Iterator[None]:
    """One writer at a time on this machine: an exclusive advisory lock (``flock``) on the file ``path`` while the
    block runs, refused (ValueError starting with ``what``, naming the holder) when another process holds it. The
    system releases the lock of a killed process, so a resume after ``kill -9`` needs nothing removed; the file goes
    when the block ends. Without ``fcntl`` (Windows): the exclusive create of ``writer_lock``."""
    try:
        import fcntl
    except ImportError:
        with writer_lock(path, what):
            yield
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            # the file may have been removed (and another made) between our open and the lock: then ours is stale
            held = os.fstat(fd).st_ino == os.stat(path).st_ino
        except (BlockingIOError, FileNotFoundError):
            held = False
        if not held:
            try:
                holder = json.loads(path.read_text(encoding="utf-8"))
                who = f"pid {holder['pid']} since {time.strftime('%Y-%m-%d %H:%M:%S', time.localtime(holder['started']))}"
            except (OSError, ValueError, KeyError, TypeError):
                who = "being started"
            raise ValueError(f"{what} is running ({who}; lock {path}); wait for it to end")
        os.ftruncate(fd, 0)
        os.write(fd, (json.dumps({"host": socket.gethostname(), "pid": os.getpid(), "started": time.time()}) + "\n").encode())
        try:
            yield
        finally:
            path.unlink(missing_ok=True)  # before the lock goes: a waiting process then finds no file, or a new one
    finally:
        os.close(fd)
