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
