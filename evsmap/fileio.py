"""Writing output folders safely."""

from __future__ import annotations

import contextlib
import os
import shutil
from collections.abc import Iterator
from pathlib import Path

from evsmap.errors import EvsmapError


@contextlib.contextmanager
def staging_folder(out: Path, *, overwrite: bool, source: Path | None = None,
                   what: str = "") -> Iterator[Path]:
    """Yield an empty hidden folder beside ``out``; once the block ends without error it replaces
    ``out`` (so an existing ``out`` is never left half-written); on error it is removed.

    A non-empty ``out`` is refused unless ``overwrite``; ``out`` may not be or contain ``source``.
    Messages start with ``what`` (e.g. ``"--out "``) and the folder.
    """
    out = Path(out)
    name = f"{what}{out}"
    if out.exists() and not out.is_dir():
        raise EvsmapError(f"{name}: exists and is not a folder")
    dst = out.resolve()
    if source is not None:
        src = Path(source).resolve()
        if dst == src or dst in src.parents:
            raise EvsmapError(f"{name}: the output folder would replace the source {source}")
    if out.is_dir() and any(out.iterdir()) and not overwrite:
        raise EvsmapError(f"{name}: folder exists and is not empty (pass --overwrite)")
    parent = dst.parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise EvsmapError(f"{name}: cannot create parent folder ({exc})") from None
    partial = parent / f".{dst.name}.partial-{os.getpid()}"
    shutil.rmtree(partial, ignore_errors=True)
    try:
        partial.mkdir()
        yield partial
        if dst.exists():
            old = parent / f".{dst.name}.old-{os.getpid()}"
            dst.rename(old)
            partial.rename(dst)
            shutil.rmtree(old, ignore_errors=True)
        else:
            partial.rename(dst)
    except OSError as exc:
        raise EvsmapError(f"{name}: cannot write ({exc})") from None
    finally:
        shutil.rmtree(partial, ignore_errors=True)
