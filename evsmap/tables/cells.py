"""The printed-cell grammar of ``paper_tables.toml``: printed text -> :class:`Cell`.

A cell is printed as one of:

* a number with its printed precision, optionally followed by the column's unit and marks:
  ``"92.0"``, ``"108"``, ``"7.9†"``, ``"4.5M"`` (``"%"`` is never written);
* ``"-"`` (:data:`BLANK`): the paper leaves the cell empty;
* in a flag column, ``"√"`` (:data:`CHECK`) or ``""``.

:func:`make_cell` reads the text against its column into a :class:`Cell`, its value in base
units (``printed number x unit``); it raises :class:`ValueError` with a message that the file's
validator (:mod:`evsmap.tables.models`) prefixes with the cell's place.
"""

from __future__ import annotations

import functools
import re

from evsmap.tables.records import BLANK, CHECK, MARKS, Cell, Column

_NUMBER = re.compile(r"^(\d+)(?:\.(\d+))?$")


def not_a_number(printed: str) -> str:
    return f"{printed!r} is not a number (write \"{BLANK}\" for a blank cell)"


def split_marks(printed: str) -> tuple[str, tuple[str, ...]]:
    """``"7.9†"`` -> ``("7.9", ("†",))``: the text without its trailing marks, and the marks."""
    text = printed
    marks: list[str] = []
    while text and any(text.endswith(m) for m in MARKS):
        mark = next(m for m in MARKS if text.endswith(m))
        marks.insert(0, mark)
        text = text[: -len(mark)]
    return text, tuple(marks)


def make_cell(table: str, row: str, column: Column, printed: str, *, bold: bool = False,
              hardware: str | None = None, note: str = "") -> Cell:
    """The :class:`Cell` ``printed`` in ``column``.

    Raises:
        ValueError: a flag column holds something other than a check mark or nothing, or a
            number column something that is not a number in its unit.
    """
    cell = functools.partial(Cell, table=table, row=row, column=column.id, unit=column.unit,
                             bold=bold, hardware=hardware, note=note)
    if column.quantity == "flag":
        if printed not in (CHECK, ""):
            raise ValueError(f"a flag cell is {CHECK!r} or '', got {printed!r}")
        return cell(value=1.0 if printed == CHECK else 0.0, number=None, decimals=None,
                    printed=printed)
    if printed == BLANK:
        return cell(value=None, number=None, decimals=None, printed=printed)
    text, marks = split_marks(printed)
    if column.unit and text.endswith(column.unit) and column.unit != "%":
        text = text[: -len(column.unit)]  # "4.5M" written with its unit
    match = _NUMBER.match(text)
    if not match:
        raise ValueError(not_a_number(printed))
    number = float(text)
    return cell(value=number * column.scale, number=number, decimals=len(match.group(2) or ""),
                marks=marks, printed=text + "".join(marks))
