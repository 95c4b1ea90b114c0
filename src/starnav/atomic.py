"""Crash-safe file output: write to a temporary name in the same directory, then rename.

A reader never sees a half-written file: either the old content or the new one. Every file
starnav writes goes through :func:`atomic_path` (or the two helpers built on it).

Durable on power loss: the temporary file is flushed to the disk (``fsync``) before the
rename, and the directory after it (POSIX makes neither implicit). Every write does it (its
cost: docs/performance.md). A failed write that the system reports without a file name
(``write``, ``fsync``: ENOSPC, EIO) is re-raised naming the file being written.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path


def current_umask() -> int:
    """The process's umask (read without changing it)."""
    umask = os.umask(0)
    os.umask(umask)
    return umask


def _sync_file(fd: int) -> None:
    """Flush an open file's data and metadata to the disk (the lowest write step)."""
    os.fsync(fd)


def sync_file(path: str | os.PathLike[str]) -> None:
    """``fsync`` the file at ``path``."""
    fd = os.open(path, os.O_RDONLY)
    try:
        _sync_file(fd)
    finally:
        os.close(fd)


def sync_directory(path: str | os.PathLike[str]) -> None:
    """``fsync`` the directory ``path``: its entries (a rename into it) reach the disk."""
    fd = os.open(path, os.O_RDONLY | os.O_DIRECTORY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


@contextmanager
def atomic_path(path: str | os.PathLike[str], suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; rename it to ``path`` when the block exits
    normally, delete it otherwise. ``suffix`` (default: ``path``'s own) keeps writers that
    choose their format from the extension happy. Parent directories are created. The file is
    fsynced before the rename and its directory after it (module docstring)."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=suffix if suffix is not None
                               else (p.suffix or ".tmp"), dir=p.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        os.chmod(tmp_path, 0o666 & ~current_umask())  # mkstemp creates 0600
        sync_file(tmp_path)
        os.replace(tmp_path, p)
    except OSError as err:
        tmp_path.unlink(missing_ok=True)
        if err.filename is None:  # write(), fsync(): say which file could not be written
            raise OSError(err.errno, err.strerror or str(err), str(p)) from err
        raise
    except BaseException:
        tmp_path.unlink(missing_ok=True)
        raise
    sync_directory(p.parent)


def atomic_write_bytes(path: str | os.PathLike[str], data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically; returns the path."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return Path(path)


def atomic_write_text(path: str | os.PathLike[str], text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically; returns the path."""
    return atomic_write_bytes(path, text.encode("utf-8"))
