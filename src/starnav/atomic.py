"""Crash-safe file output: write to a temporary name in the same directory, then rename.

A reader never sees a half-written file: either the old content or the new one. Every file
starnav writes goes through :func:`atomic_path` (or the two helpers built on it).

Example
-------
>>> from starnav.atomic import atomic_path
>>> with atomic_path("out/x.png") as tmp:          # doctest: +SKIP
...     imageio.imwrite(tmp, image)                # written to a temporary name
>>> # renamed to out/x.png only if the block succeeded
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path


def _default_mode() -> int:
    umask = os.umask(0)
    os.umask(umask)
    return 0o666 & ~umask


@contextmanager
def atomic_path(path: str | os.PathLike[str], suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; rename it to ``path`` when the block exits
    normally, delete it otherwise. ``suffix`` (default: ``path``'s own) keeps writers that
    choose their format from the extension happy. Parent directories are created."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=suffix if suffix is not None
                               else (p.suffix or ".tmp"), dir=p.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        os.chmod(tmp_path, _default_mode())  # mkstemp creates 0600
        os.replace(tmp_path, p)
    except BaseException:
        tmp_path.unlink(missing_ok=True)
        raise


def atomic_write_bytes(path: str | os.PathLike[str], data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically; returns the path."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return Path(path)


def atomic_write_text(path: str | os.PathLike[str], text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically; returns the path."""
    return atomic_write_bytes(path, text.encode("utf-8"))
