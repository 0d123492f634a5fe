"""Errors that are the user's to fix.

Anything raised as an :class:`EvsmapError` reaches the command line as one line on stderr and exit
status 2 (see :mod:`evsmap.cli.main`); everything else is a bug in evsmap and keeps its traceback.
"""

from __future__ import annotations


class EvsmapError(Exception):
    """Base class of errors caused by input or options (a file, a name, a value)."""


class UnknownNameError(EvsmapError, KeyError):
    """A plug-in name that no registry holds."""

    def __str__(self) -> str:  # KeyError would quote the message
        return str(self.args[0]) if self.args else ""


class DuplicateNameError(EvsmapError, ValueError):
    """A plug-in name registered twice."""


class InvalidDataError(EvsmapError, ValueError):
    """An array or record with the wrong shape, dtype or values."""


class DataFormatError(EvsmapError):
    """A file or folder that is missing, corrupt or not in the expected layout."""
