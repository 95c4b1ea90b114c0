"""The starnav exception tree.

Every error raised on purpose by starnav derives from :class:`StarnavError` and from the builtin
it refines, so ``except ValueError`` keeps working for callers that do not know starnav. Messages
name the offending field, the value received and what was expected.
"""

from __future__ import annotations

import os
from typing import Any


class StarnavError(Exception):
    """Root of every error raised on purpose by starnav."""


#: Longest value an error message quotes [characters]: a long list is cut, not echoed whole.
MAX_SHOWN_VALUE = 200


def shown_value(value: Any) -> str:
    """``repr(value)``, cut to :data:`MAX_SHOWN_VALUE` characters with its full length said."""
    text = repr(value)
    if len(text) <= MAX_SHOWN_VALUE:
        return text
    return f"{text[:MAX_SHOWN_VALUE]}... ({len(text)} characters)"


class ConfigError(StarnavError, ValueError):
    """Invalid configuration or argument: names the field, the value and what was expected."""

    def __init__(self, field: str, value: Any, expected: str) -> None:
        self.field = field
        self.value = value
        self.expected = expected
        super().__init__(f"{field} = {shown_value(value)}: expected {expected}")


class GeometryError(StarnavError, ValueError):
    """Impossible geometry (observer inside the Moon, target behind the camera, ...)."""


class DataFileError(StarnavError, FileNotFoundError):
    """A data file is missing or unreadable."""


def not_a_file_error(path: Any, what: str) -> DataFileError:
    """The error for an input ``path`` that is not a regular file, saying what it is instead:
    missing, a directory, or a device or pipe (``/dev/null``). ``what`` names the input
    (``"OEM file"``)."""
    p = os.fspath(path)
    if os.path.isdir(p):
        return DataFileError(f"{what} {p!r} is a directory: expected a file")
    if os.path.exists(p):
        return DataFileError(f"{what} {p!r} is not a regular file (a device or a pipe): "
                             "expected a file")
    return DataFileError(f"{what} {p!r} does not exist")


class BackendError(StarnavError, RuntimeError):
    """No usable rendering backend."""


class UnknownNameError(StarnavError, KeyError):
    """A name not present in a registry; the message lists the known names."""

    def __init__(self, kind: str, name: str, known: list[str] | tuple[str, ...]) -> None:
        self.kind = kind
        self.name = name
        self.known = tuple(sorted(known))
        super().__init__(f"unknown {kind} {name!r}; known: {', '.join(self.known)}")

    def __str__(self) -> str:  # KeyError would quote the message otherwise
        return str(self.args[0])
