"""Which reader reads a path, and a sequence opened with it (``evsmap info``, ``map``, ``eval``,
``predict``, ``train`` and the runner open their sequences here)."""

from __future__ import annotations

from pathlib import Path

from evsmap.data import Sequence
from evsmap.errors import DataFormatError, EvsmapError
from evsmap.registry import READERS


def detect_reader(path: Path) -> str:
    """Name of the first registered reader whose ``detect`` accepts ``path``.

    Raises:
        DataFormatError: ``path`` does not exist, or no reader recognises it.
    """
    if not path.exists():
        raise DataFormatError(f"{path}: no such file or folder")
    for entry in READERS.entries():
        detect = entry.extras.get("detect")
        if detect is not None and detect(path):
            return entry.name
    known = [e.name for e in READERS.entries() if e.extras.get("detect")]
    raise DataFormatError(f"{path}: layout not recognised (readers tried: {', '.join(known)})")


def open_sequence(text: str, reader: str | None = None,
                  options: list[tuple[str, object]] | None = None) -> Sequence:
    """A sequence from a path (reader detected unless named) or the name of a reader that needs
    no path (e.g. ``synthetic``), built with the given reader options."""
    config = dict(options or [])
    path = Path(text)
    if reader is None and not path.exists() and text in READERS.names() and \
            "path" not in READERS.get(text).parameters():
        return READERS.create(text, **config)
    name = reader or detect_reader(path)
    if "path" not in READERS.get(name).parameters():
        raise EvsmapError(f"reader {name!r} takes no path; pass its name instead of {text!r}")
    if reader is not None and not path.exists():
        raise EvsmapError(f"{path}: no such file or folder")
    return READERS.create(name, path=str(path), **config)


__all__ = ["detect_reader", "open_sequence"]
