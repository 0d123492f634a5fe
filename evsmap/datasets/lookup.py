"""A labelled dataset named as the commands name one: a folder (its reader detected), a prepared
dataset's name (looked up in ``datasets/NAME`` and the data root) or a reader that needs no
path (e.g. ``synthetic``); its split, and its classes (``evsmap eval``, ``predict``, ``train``
and the runner find datasets here)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from evsmap.errors import EvsmapError

if TYPE_CHECKING:
    from evsmap.data import Sequence

DEFAULT_SPLIT = {"cityscapes": "val"}
"""Split evaluated when ``--split`` is not given, by reader (Table II uses Cityscapes' val, the
test labels are not public); every other reader with splits: ``test``."""


def find_dataset(text: str, reader: str | None) -> tuple[str, str | None]:
    """``(path or reader name, reader)``: a bare name that is not a path becomes the folder of
    that name in ``datasets/`` or the data root (a prepared dataset, ``nyuv2``, or a sample,
    ``nyuv2_samples``), its reader the one the name names, else detected.

    Raises:
        EvsmapError: ``text`` names a reader that reads a folder and no prepared folder of that
            name was found.
    """
    from evsmap.paths import default_data_root
    from evsmap.registry import READERS

    path = Path(text)
    if path.exists():
        return text, reader
    is_reader = reader is None and text in READERS.names()
    if is_reader and not READERS.get(text).takes.path:
        return text, None  # e.g. synthetic: built from options
    roots = [Path("datasets")]
    data_root = default_data_root()
    if data_root is not None:
        roots.append(data_root)
    if len(path.parts) == 1:  # a bare name: a folder of that name in datasets/ or the data root
        for root in roots:
            if (root / text).is_dir():
                return str(root / text), reader or (text if is_reader else None)
    looked = ", ".join(str(r / text) for r in roots)
    if not is_reader:
        if len(path.parts) == 1 and not text.startswith("."):
            raise EvsmapError(f"{text}: no such file or folder, nor a dataset of that name "
                              f"(looked in {looked}; `evsmap datasets list` shows the prepared "
                              f"ones)")
        return text, reader
    raise EvsmapError(f"reader {text!r} reads a folder and none was found (looked in {looked}): "
                      f"pass --dataset PATH, or prepare it with `evsmap datasets prepare {text}`")


def reader_name(text: str, reader: str | None) -> str:
    """The reader of ``text`` (as :func:`find_dataset` returns it): ``reader`` when named, the
    reader ``text`` names when it is not a path, else the detected one."""
    from evsmap.readers.detect import detect_reader
    from evsmap.registry import READERS

    if reader is not None:
        return reader
    path = Path(text)
    if not path.exists() and text in READERS.names():
        return text
    return detect_reader(path)


def open_dataset(text: str, *, reader: str | None = None, split: str | None = None,
                 limit: int | None = None, options: list[tuple[str, object]] | None = None):
    """The labelled sequence to score and a description ``{reader, split, limit_applied}``.

    ``split`` and ``limit`` go to readers that take them (``READERS.get(name).takes``);
    a reader without splits refuses an explicit ``split``; ``limit`` is applied while reading
    otherwise.
    """
    from evsmap.readers.detect import open_sequence
    from evsmap.registry import READERS

    text, reader = find_dataset(text, reader)
    name = reader_name(text, reader)
    takes = READERS.get(name).takes
    config = dict(options or [])
    if takes.split:
        config.setdefault("split", split or DEFAULT_SPLIT.get(name, "test"))
    elif split is not None:
        raise EvsmapError(f"reader {name!r} has no splits: leave out --split")
    if limit is not None and takes.limit:
        config.setdefault("limit", limit)
    sequence = open_sequence(text, reader, list(config.items()))
    return sequence, {"reader": name, "split": config.get("split")}


def dataset_classes(sequence: Sequence) -> tuple[int | None, tuple[str, ...]]:
    """The dataset's class count and names (:attr:`Sequence.num_classes`,
    :attr:`Sequence.class_names`); ``(None, ())`` when the reader does not say."""
    return sequence.num_classes, tuple(sequence.class_names)


__all__ = ["DEFAULT_SPLIT", "dataset_classes", "find_dataset", "open_dataset", "reader_name"]
