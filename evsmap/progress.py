"""Progress bars that show on a terminal and stay silent when stderr is not one."""

from __future__ import annotations

import sys
from collections.abc import Iterable, Iterator, Sized
from typing import TypeVar

from tqdm import tqdm

T = TypeVar("T")


def progress(items: Iterable[T], *, total: int | None = None, desc: str = "",
             unit: str = "frame") -> Iterator[T]:
    """``tqdm`` over ``items`` on a TTY, the plain iterator otherwise."""
    if total is None and isinstance(items, Sized):
        total = len(items)
    return iter(tqdm(items, total=total, desc=desc, unit=unit, leave=False,
                     disable=not sys.stderr.isatty(), file=sys.stderr))
