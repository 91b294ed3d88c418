"""Atomic file writes: a reader sees either the old file or the complete new one, never a torn file.

A write that fails for want of space or quota raises solver.errors.DiskFullError (naming the file and the free
bytes; exit code 3), so every writer reports a full disk in one line.
"""

import contextlib
import errno
import os
import shutil
import tempfile
from pathlib import Path

from solver.errors import DiskFullError

DISK_FULL_ERRNOS = {errno.ENOSPC: "no space left on the device", errno.EDQUOT: "disk quota exceeded"}


def free_bytes(path) -> int | None:
    """Free bytes on the file system holding `path` (or its nearest existing parent), None if unknown."""
    path = Path(path).absolute()
    for candidate in (path, *path.parents):
        try:
            return shutil.disk_usage(candidate).free
        except OSError:
            continue
    return None


@contextlib.contextmanager
def disk_full_as_error(path):
    """Turn an OSError ENOSPC/EDQUOT raised inside the block into DiskFullError naming `path`."""
    try:
        yield
    except OSError as err:
        if err.errno not in DISK_FULL_ERRNOS:
            raise
        raise DiskFullError(path, free_bytes(path), DISK_FULL_ERRNOS[err.errno]) from err


def atomic_write_bytes(path, data: bytes, *, backup_suffix: str | None = None) -> Path:
    """Write `data` to `path` through a temporary file in the same directory, fsync, then rename.

    If `backup_suffix` is given and `path` exists, the old file is kept as `path + backup_suffix`
    (by hard link, so it is never missing even if we crash between the steps).
    """
    path = Path(path)
    with disk_full_as_error(path):
        _atomic_write(path, data, backup_suffix)
    return path


def _atomic_write(path: Path, data: bytes, backup_suffix: str | None) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as tmp:
            tmp.write(data)
            tmp.flush()
            os.fsync(tmp.fileno())
        if backup_suffix and path.exists():
            backup = path.with_name(path.name + backup_suffix)
            backup_tmp = backup.with_name(backup.name + ".tmp")
            if backup_tmp.exists():
                backup_tmp.unlink()
            os.link(path, backup_tmp)
            os.replace(backup_tmp, backup)
        os.replace(tmp_name, path)
    except BaseException:
        if os.path.exists(tmp_name):
            os.unlink(tmp_name)
        raise
    fsync_directory(path.parent)


def atomic_write_text(path, text: str, **kwargs) -> Path:
    return atomic_write_bytes(path, text.encode("utf-8"), **kwargs)


def fsync_directory(directory) -> None:
    """Make a rename or a new file in `directory` durable."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)
