"""The C rasterizer kernel (``raster_cpu.c``): built on first use into a per-user cache, loaded with ctypes.

The library lives in ``$XDG_CACHE_HOME`` (else ``~/.cache``) under ``trioman/kernels/<sha256>.so``, the
hash over the source and the compiler command; it is written to a temporary file in that folder and
renamed into place, so a reader never sees a half-written library and concurrent builds are safe. The
library has no threads of its own (a second OpenMP runtime beside torch's aborted processes at exit): the
caller runs disjoint tile ranges on Python threads, which ctypes calls release the GIL for. The
compiler is ``$CC`` (else ``cc``). ``TRIOMAN_NATIVE=0`` turns the kernel off. When the build or the load
fails, :func:`load` warns once and returns None, and the renderer keeps its torch path.
"""

from __future__ import annotations

import ctypes
import functools
import hashlib
import os
import shlex
import subprocess
import tempfile
import warnings
from pathlib import Path

SOURCE = Path(__file__).with_name("raster_cpu.c")
ENV_SWITCH = "TRIOMAN_NATIVE"
FLAGS = ("-O3", "-fPIC", "-shared", "-fno-fast-math", "-ffp-contract=off")

_P, _I64 = ctypes.c_void_p, ctypes.c_int64
# gq, radii, pair_gauss, tile_start, tile_count, tiles_x, s, width, height, then the tile range t0, t1
_SCENE = [_P] * 5 + [_I64] * 6
_SIGNATURES = {
    "raster_forward": _SCENE + [_P] * 3,  # color, T_final, last
    "raster_backward": _SCENE + [_P] * 5,  # T_final, last, g_color, g_T, g_pair
    "raster_sum_pairs": [_P, _I64, _P, _P],  # pair_gauss, n_pairs, g_pair, g_gq
}

_loaded: dict[str, ctypes.CDLL | None] = {}  # by library name: the outcome of the first attempt


def compiler_command(output: Path) -> list[str]:
    """The command that compiles SOURCE into the shared library ``output``."""
    return [*shlex.split(os.environ.get("CC") or "cc"), *FLAGS, str(SOURCE), "-o", str(output), "-lm"]


def cache_dir() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "trioman" / "kernels"


def load() -> ctypes.CDLL | None:
    """The kernel library (built when missing), or None when ``TRIOMAN_NATIVE=0`` or it cannot be built."""
    if os.environ.get(ENV_SWITCH, "1") == "0":
        return None
    path = cache_dir() / _library_name(tuple(compiler_command(Path("OUT"))))
    if path.name not in _loaded:
        _loaded[path.name] = _build_and_load(path)
    return _loaded[path.name]


@functools.lru_cache
def _library_name(command: tuple[str, ...]) -> str:
    """<sha256 of the source and the compiler command>.so (the source read once per process and command)."""
    return hashlib.sha256(SOURCE.read_bytes() + "\0".join(command).encode()).hexdigest() + ".so"


def _build_and_load(path: Path) -> ctypes.CDLL | None:
    command = compiler_command(path)
    try:
        if not path.exists():
            _build(path)
        lib = ctypes.CDLL(str(path))
    except (OSError, subprocess.CalledProcessError) as err:
        detail = err.stderr.strip() if isinstance(err, subprocess.CalledProcessError) else str(err)
        warnings.warn(f"the C rasterizer kernel is unavailable ({shlex.join(command)}: {detail}); "
                      "rendering on the torch path", RuntimeWarning, stacklevel=3)
        return None
    for fn, argtypes in _SIGNATURES.items():
        getattr(lib, fn).argtypes = argtypes
        getattr(lib, fn).restype = ctypes.c_int
    return lib


def _build(path: Path) -> None:
    """Compile into a temporary file beside ``path``, then rename it into place."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".build-", suffix=".so")
    os.close(fd)
    try:
        subprocess.run(compiler_command(Path(tmp)), check=True, capture_output=True, text=True)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
