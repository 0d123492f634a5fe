"""Argument types shared by the commands (each error names the option's value)."""

from __future__ import annotations

import argparse
from collections.abc import Callable

from evsmap.options import parse_key_value


def _int_at_least(lowest: int, what: str) -> Callable[[str], int]:
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = lowest - 1
        if value < lowest:
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}")
        return value

    parse.__name__ = what  # argparse names the type in some messages
    return parse


def positive_float(text: str) -> float:
    """A finite number above 0."""
    try:
        value = float(text)
    except ValueError:
        value = -1.0
    if not value > 0 or value != value or value == float("inf"):
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}")
    return value


def image_size(text: str) -> tuple[int, int]:
    """``HEIGHTxWIDTH`` in pixels (``480x640``)."""
    h, sep, w = text.lower().partition("x")
    try:
        size = (int(h), int(w)) if sep else (0, 0)
    except ValueError:
        size = (0, 0)
    if min(size) < 1:
        raise argparse.ArgumentTypeError(f"expected HEIGHTxWIDTH in pixels (e.g. 480x640), "
                                         f"got {text!r}")
    return size


positive_int = _int_at_least(1, "a positive integer")
nonnegative_int = _int_at_least(0, "an integer >= 0")


def key_value(text: str) -> tuple[str, object]:
    """``KEY=VALUE`` for a plug-in option; VALUE is read as a bool (true/false), an int, a float
    or else kept as a string (:func:`evsmap.options.parse_key_value`, its error as argparse's)."""
    try:
        return parse_key_value(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
