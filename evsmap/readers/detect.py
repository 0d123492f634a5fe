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
    if path.is_dir() and not any(path.iterdir()):
        raise DataFormatError(f"{path}: the folder is empty (give a sequence or dataset folder, "
                              f"or a bag)")
    known = [e.name for e in READERS.entries() if e.extras.get("detect")]
    raise DataFormatError(f"{path}: layout not recognised (readers tried: {', '.join(known)}); "
                          f"name the reader with --reader NAME, or see the layouts each expects "
                          f"in docs/datasets.md")


def pathless_reader(text: str, reader: str | None = None) -> str | None:
    """The reader ``text`` names when it is a reader that needs no path (``synthetic``, with or
    without ``--reader`` naming the same reader) and no file of that name exists; else None."""
    if Path(text).exists() or text not in READERS.names() or reader not in (None, text):
        return None
    return None if READERS.get(text).takes.path else text


def sequence_reader(text: str, reader: str | None = None) -> str:
    """The reader :func:`open_sequence` reads ``text`` with."""
    return pathless_reader(text, reader) or reader or detect_reader(Path(text))


def open_sequence(text: str, reader: str | None = None,
                  options: list[tuple[str, object]] | None = None) -> Sequence:
    """A sequence from a path (reader detected unless named) or the name of a reader that needs
    no path (e.g. ``synthetic``), built with the given reader options."""
    config = dict(options or [])
    path = Path(text)
    if pathless_reader(text, reader) is not None:
        return READERS.create(text, **config)
    name = reader or detect_reader(path)
    if not READERS.get(name).takes.path:
        raise EvsmapError(f"reader {name!r} takes no path: give {name!r} as the sequence "
                          f"(not {text!r}), or leave out --reader to read {text!r} with the "
                          f"reader its layout needs")
    if reader is not None and not path.exists():
        raise EvsmapError(f"{path}: no such file or folder")
    return READERS.create(name, path=str(path), **config)


__all__ = ["detect_reader", "open_sequence", "pathless_reader", "sequence_reader"]
