"""Fault injection shared by the worker-death tests: a worker process that kills itself at a
fixed point of the code, once per cluster (never on a timer, so machine load cannot decide
whether the kill lands)."""

from __future__ import annotations

import os
import signal


def die_once(marker: str, note: str) -> None:
    """SIGKILL this process if it is the first to claim ``marker`` (created with O_EXCL, holding
    ``note``: where it died); return without effect for every later caller."""
    try:
        fd = os.open(marker, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
    except FileExistsError:
        return
    os.write(fd, note.encode())
    os.close(fd)
    os.kill(os.getpid(), signal.SIGKILL)
