"""What an earlier ``starnav render`` left in an output directory, and its removal.

``starnav render`` writes ``frame_NNNNNN.<ext>`` (the EXR, and its quick-look pictures) and
``scenario.resolved.yaml`` into its output directory. A second run into the same directory
would otherwise overwrite some frames and leave the others beside a resolved scenario that
describes only the new run. So a render refuses a directory holding an earlier run's outputs
(:func:`check_render_directory`) unless told to replace them (``--overwrite``), which removes
exactly those files before the first new frame is written; anything else in the directory (a
user's notes) is left alone.
"""

from __future__ import annotations

import logging
import re
from pathlib import Path

from starnav.errors import DataFileError

log = logging.getLogger(__name__)

#: A frame file of ``starnav render``: ``frame_000012.exr``, ``frame_000012.png``,
#: ``frame_000012_quicklook.png``, ...
FRAME_FILE = re.compile(r"^frame_(\d{6})(_quicklook)?\.[A-Za-z0-9.]+$")
#: The resolved scenario written next to the frames.
RESOLVED = "scenario.resolved.yaml"


def previous_render(out: Path) -> list[Path]:
    """The files of an earlier render in ``out`` (frame files and the resolved scenario)."""
    if not out.is_dir():
        return []
    return sorted(p for p in out.iterdir()
                  if p.is_file() and (FRAME_FILE.match(p.name) or p.name == RESOLVED))


def check_render_directory(out: Path, overwrite: bool) -> None:
    """Refuse ``out`` if it holds an earlier render's outputs, or remove them (``overwrite``).

    Raises
    ------
    DataFileError
        ``out`` is a file, or holds an earlier render and ``overwrite`` is false.
    """
    if out.exists() and not out.is_dir():
        raise DataFileError(f"output {str(out)!r} exists and is not a directory")
    old = previous_render(out)
    if not old:
        return
    frames = sorted({m.group(1) for p in old if (m := FRAME_FILE.match(p.name))})
    if not overwrite:
        shown = ", ".join(p.name for p in old[:3]) + (" ..." if len(old) > 3 else "")
        raise DataFileError(
            f"output {str(out)!r} holds {len(frames)} frame(s) of an earlier render ({shown}): "
            "expected a new or empty directory; use --overwrite to replace that run, or "
            "choose another --out")
    for p in old:
        log.info("removing %s of the earlier render", p)
        p.unlink()
