"""Options shared by the commands that read a sequence (``info``, ``map``): the reader, its
options and ``--skip-bad``."""

from __future__ import annotations

import argparse
from pathlib import Path

from evsmap.cli.options import key_value
from evsmap.data import Sequence
from evsmap.errors import EvsmapError


def add_sequence_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--reader", metavar="NAME",
                   help="use this reader instead of detecting one from the path (evsmap list)")
    p.add_argument("-r", "--reader-option", type=key_value, action="append", default=[],
                   metavar="KEY=VALUE",
                   help="a reader option, repeatable (e.g. -r preset=asl, -r split=test, "
                        "-r limit=10, -r depth_topic=/camera/depth)")
    p.add_argument("--skip-bad", action="store_true",
                   help="leave out frames that cannot be read (corrupt image, wrong dtype or "
                        "size, no pose at the frame's time, ...) and report how many and why, "
                        "instead of stopping at the first")


def open_sequence(text: str, reader: str | None = None,
                  options: list[tuple[str, object]] | None = None) -> Sequence:
    """A sequence from a path (reader detected unless named) or the name of a reader that needs
    no path (e.g. ``synthetic``), built with the given reader options."""
    from evsmap.cli.info_cmd import detect_reader
    from evsmap.registry import READERS

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
