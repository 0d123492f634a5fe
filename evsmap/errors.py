"""Errors that are the user's to fix.

Anything raised as an :class:`EvsmapError` reaches the command line as one line on stderr and exit
status 2 (see :mod:`evsmap.cli.main`); everything else is a bug in evsmap and keeps its traceback.
"""

from __future__ import annotations

import difflib
from collections.abc import Iterable


class EvsmapError(Exception):
    """Base class of errors caused by input or options (a file, a name, a value)."""


class UnknownNameError(EvsmapError, KeyError):
    """A plug-in name that no registry holds."""

    def __str__(self) -> str:  # KeyError would quote the message
        return str(self.args[0]) if self.args else ""


def unknown_name(kind: str, name: str, known: Iterable[str]) -> UnknownNameError:
    """The error for ``name``, which no ``kind`` registry holds: the closest known name and
    every known one."""
    names = sorted(known)
    close = difflib.get_close_matches(name, names, n=1, cutoff=0.4)
    hint = f"; did you mean {close[0]!r}?" if close else ""
    listed = ", ".join(names) if names else "none registered"
    return UnknownNameError(f"unknown {kind} {name!r}{hint} (known: {listed})")


class DuplicateNameError(EvsmapError, ValueError):
    """A plug-in name registered twice."""


class InvalidDataError(EvsmapError, ValueError):
    """An array or record with the wrong shape, dtype or values."""


class DataFormatError(EvsmapError):
    """A file or folder that is missing, corrupt or not in the expected layout."""
