"""The CLI's consoles, its one error printer (every command's errors look alike) and its one
overwrite rule (:func:`check_output`, called by every command that writes, before any work).

Errors are printed on one line whatever the terminal width (``soft_wrap``): a message names a
field, a value and what was expected, and a test or a user grepping for it must find it whole.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable
from pathlib import Path

import typer
from rich.console import Console
from rich.markup import escape

from starnav.errors import DataFileError

console = Console()
err_console = Console(stderr=True, soft_wrap=True)


def print_error(err: Exception | str) -> None:
    """Print ``error: <message>`` as one line on stderr (never wrapped; rich markup in the
    message, e.g. a list in brackets, is printed as it is)."""
    err_console.print(f"[bold red]error:[/] {escape(str(err))}", soft_wrap=True)


def fail(err: Exception | str) -> None:
    """Print the error and exit with status 2 (bad input)."""
    print_error(err)
    raise typer.Exit(code=2)


def os_error_message(err: OSError, resumable: bool = False) -> str:
    """One line for a failed read or write: the path, what the system said, and the hint
    (``resumable``: the command keeps its work and continues it with ``--resume``)."""
    import errno as _errno

    name = _errno.errorcode.get(err.errno or 0, "")
    path = err.filename if err.filename is not None else "<path>"
    extra = f" -> {err.filename2}" if getattr(err, "filename2", None) else ""
    hint = {"ENOSPC": "the disk is full: free some space, then run again"
            + (" with --resume, which keeps the frames already made" if resumable else ""),
            "EACCES": "choose a writable place",
            "EPERM": "choose a writable place", "EROFS": "choose a writable place",
            "ENOTDIR": "a path component is a file, not a directory",
            "EISDIR": "expected a file, found a directory",
            "ENOENT": "check the path"}.get(name, "check the path and its permissions")
    return f"{path}{extra}: {err.strerror or err} ({name or 'OSError'}); {hint}"


def print_table(title: str, headers: list[str] | None, rows: list[list[str]],
                out: Console | None = None) -> None:
    """Print a table whose cells are never cut.

    On a terminal: a rich table whose columns fold long cells onto more lines (never an
    ellipsis). In a pipe or a file (not a terminal, whatever ``COLUMNS`` says): plain text, one
    line per row, columns padded to their widest cell, so the labels that tell rows apart are
    whole and a script can read them.
    """
    from rich.table import Table

    c = out or console
    if c.is_terminal:
        t = Table(title=title, show_header=headers is not None)
        for h in headers or [""] * (len(rows[0]) if rows else 0):
            t.add_column(escape(h), overflow="fold")
        for r in rows:
            t.add_row(*(escape(x) for x in r))
        c.print(t)
        return
    cells = ([headers] if headers else []) + rows
    widths = [max(len(r[j]) for r in cells) for j in range(len(cells[0]))] if cells else []
    lines = [title]
    for i, r in enumerate(cells):
        lines.append("  ".join(x.ljust(w) for x, w in zip(r, widths, strict=True)).rstrip())
        if headers and i == 0:
            lines.append("  ".join("-" * w for w in widths))
    typer.echo("\n".join(lines))


def format_quantity(key: str, value: object) -> str:
    """A summary value with the unit its key names in brackets and sensible digits:
    ``("limb bias [px]", 0.875992)`` -> ``"+0.876 px"``, ``("... [%]", 0.0123)`` ->
    ``"0.0123 %"``, ``("elapsed_s", 12.3456)`` -> ``"12.3 s"``; other values as they are."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        return str(value)
    import math
    import re

    if isinstance(value, float) and not math.isfinite(value):
        return "-"
    m = re.search(r"\[([^\]]+)\]\s*$", key)
    unit = m.group(1) if m else ("s" if key.endswith("_s") else
                                 ("frames/s" if key.endswith("_per_s") else ""))
    if key.endswith("_per_s"):
        unit = "frames/s"
    if isinstance(value, int):
        text = str(value)
    else:
        text = f"{value:+.3g}" if "bias" in key else f"{value:.3g}"
    unit = unit.replace("% range", "% of range")
    return f"{text} {unit}".strip()


def _inside(path: Path, root: Path) -> bool:
    """Whether ``path`` is ``root`` or lies under it (both resolved, symbolic links followed)."""
    return path == root or root in path.parents


def check_output(path: Path, *, directory: bool, overwrite: bool = False,
                 inputs: Iterable[Path | None] = (), option: str = "--out",
                 flag: str = "--overwrite", side_files: Iterable[Path] = (),
                 ours: Callable[[Path], bool] | None = None,
                 action: str = "write into it") -> None:
    """The overwrite rule of every command that writes, checked before any work.

    1. Never write into an input: ``path`` (and each of ``side_files``, the files written next
       to it, e.g. the resolved scenario) may not be an input file, nor be or lie inside an
       input directory, whatever ``overwrite`` says.
    2. A file output (``directory`` false) that exists is refused unless ``overwrite``; a
       directory there is refused always.
    3. A directory output that exists is refused if it is a file, or if it holds anything
       unless ``overwrite`` (``flag`` names the option that allows it: ``--resume`` for a
       dataset) or ``ours(path)`` says it holds this command's own earlier output, which
       the command continues (``demo``).

    Nothing is created or changed. Raises :class:`~starnav.errors.DataFileError` naming the
    option, the path and what was expected (the CLI: one ``error:`` line, exit status 2).
    """
    target = Path(os.path.abspath(path))
    real = target.resolve()
    ins = [Path(i) for i in inputs if i is not None and str(i) not in ("", "default")]
    for out in [path, *side_files]:
        r = Path(os.path.abspath(out)).resolve()
        for i in ins:
            ri = Path(os.path.abspath(i)).resolve()
            if r == ri or (ri.is_dir() and _inside(r, ri)):
                what = "is" if r == ri else "lies inside"
                name = option if out == path else f"{option} (its side file {str(out)!r})"
                raise DataFileError(
                    f"{name} {str(out)!r} {what} the input {str(i)!r}: a command never writes "
                    f"into its input (even with {flag}); choose another {option}")
    if not target.exists() and not target.is_symlink():
        return
    if directory:
        if not real.is_dir():
            raise DataFileError(f"{option} {str(path)!r} exists and is not a directory: "
                                f"expected a new or empty directory; choose another {option}")
        entries = sorted(p.name for p in real.iterdir())
        if entries and not overwrite and not (ours is not None and ours(real)):
            shown = ", ".join(entries[:3]) + (" ..." if len(entries) > 3 else "")
            raise DataFileError(
                f"{option} {str(path)!r} is not empty ({len(entries)} entries: {shown}): "
                f"expected a new or empty directory; use {flag} to {action}, or choose "
                f"another {option}")
        return
    if real.is_dir():
        raise DataFileError(f"{option} {str(path)!r} is a directory: expected a file name")
    if not overwrite:
        raise DataFileError(f"{option} {str(path)!r} exists: expected a new file; use {flag} "
                            f"to replace it, or choose another {option}")
