"""The CLI's consoles and its one error printer (every command's errors look alike).

Errors are printed on one line whatever the terminal width (``soft_wrap``): a message names a
field, a value and what was expected, and a test or a user grepping for it must find it whole.
"""

from __future__ import annotations

import typer
from rich.console import Console
from rich.markup import escape

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


def os_error_message(err: OSError) -> str:
    """One line for a failed read or write: the path, what the system said, and the hint."""
    import errno as _errno

    name = _errno.errorcode.get(err.errno or 0, "")
    path = err.filename if err.filename is not None else "<path>"
    extra = f" -> {err.filename2}" if getattr(err, "filename2", None) else ""
    hint = {"ENOSPC": "the disk is full: free some space, then run again (a dataset: "
            "with --resume, which keeps the frames already made)",
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
