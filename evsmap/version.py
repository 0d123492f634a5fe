"""The installed evsmap's version, read from the package metadata (no import of the package's
heavy modules); "unknown" when evsmap runs from a source tree that was never installed."""

from __future__ import annotations


def evsmap_version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("evsmap")
    except PackageNotFoundError:
        return "unknown"
