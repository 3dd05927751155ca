"""``open()`` on a full disk, for the tests that patch a module's ``open`` with it: files open, writes fail with
ENOSPC."""

import errno
import os


class _FullDiskFile:
    """A file whose writes fail like a full disk's (errno ENOSPC, no file name)."""

    def __init__(self, f):
        self._f = f

    def write(self, data):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self._f.close()


def full_disk_open(path, mode="r", *args, **kw):
    """open() on a full disk: files open, writes fail."""
    f = open(path, mode, *args, **kw)
    return _FullDiskFile(f) if any(c in mode for c in "wax+") else f
