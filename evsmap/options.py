"""Plug-in options written as text: ``KEY=VALUE`` (the command line's ``-o`` / ``-r``, the
runner's ``name(k=v,...)`` specs)."""

from __future__ import annotations


def parse_value(raw: str) -> object:
    """VALUE read as a bool (true/yes/on, false/no/off), an int, a float, else kept as text
    (stripped)."""
    raw = raw.strip()
    if raw.lower() in ("true", "yes", "on"):
        return True
    if raw.lower() in ("false", "no", "off"):
        return False
    try:
        return int(raw)
    except ValueError:
        pass
    try:
        return float(raw)
    except ValueError:
        return raw


def parse_key_value(text: str) -> tuple[str, object]:
    """``KEY=VALUE`` as ``(key, value)``: the key stripped with ``-`` read as ``_``, the value
    by :func:`parse_value`.

    Raises:
        ValueError: no ``=``, or a key that is not an identifier
            (``expected KEY=VALUE, got '...'``).
    """
    key, sep, raw = text.partition("=")
    key = key.strip().replace("-", "_")
    if not sep or not key.isidentifier():
        raise ValueError(f"expected KEY=VALUE, got {text!r}")
    return key, parse_value(raw)


__all__ = ["parse_key_value", "parse_value"]
