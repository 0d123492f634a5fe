"""Options shared by the commands that read a sequence (``info``, ``map``): the reader, its
options and ``--skip-bad``."""

from __future__ import annotations

import argparse

from evsmap.cli.options import key_value


def reader_options(args: argparse.Namespace, sequence: str) -> list[tuple[str, object]]:
    """``-r`` options, with the built-in synthetic room read as a recorded sequence (rendered
    once into the cache, as Table IV reads it) unless ``-r render=live`` says otherwise."""
    options = list(args.reader_option)
    if sequence == "synthetic" and args.reader in (None, "synthetic") and \
            "render" not in dict(options):
        options.append(("render", "cached"))
    return options


def skipped_warning(skipped: dict | None, kept: int) -> str | None:
    """The warning for a ``--skip-bad`` run that left out most of the frames it tried (more than
    half): its result stands on few frames. ``skipped``: the record's ``skipped`` field."""
    count = int((skipped or {}).get("count", 0))
    tried = count + kept
    if not tried or count / tried <= 0.5:
        return None
    return (f"{count} of {tried} frames were skipped as unreadable (--skip-bad); the result "
            f"stands on {kept} (the reasons are in the record's 'skipped')")


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
