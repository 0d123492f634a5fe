"""Reading ``paper_tables.toml``: TOML -> validated models -> the tables' records.

:func:`load_tables` / :func:`load_file` read the file (by default the package's own,
:func:`default_path`); :func:`parse_tables` takes already-parsed data. Everything is checked by
:mod:`evsmap.tables.models` (a failure is a :class:`TableSchemaError` of one line naming the
file, the table, row and column); this module builds the records of
:mod:`evsmap.tables.records` from the checked models. Model cards are only named here;
:mod:`evsmap.tables.plan` resolves them (loading stays cheap: it runs in every worker).
"""

from __future__ import annotations

import tomllib
from collections.abc import Mapping
from functools import cache
from importlib import resources
from os import PathLike
from pathlib import Path
from types import MappingProxyType
from typing import Any

from evsmap.tables.cells import make_cell
from evsmap.tables.models import RowModel, TableModel, validate
from evsmap.tables.records import (
    TABLES_FILE,
    Cell,
    Column,
    Component,
    PaperTable,
    PaperTables,
    SegmenterRef,
    System,
    TableSchemaError,
)


def default_path() -> Path:
    """The package's ``paper_tables.toml``."""
    return Path(str(resources.files("evsmap.tables").joinpath(TABLES_FILE)))


def load_tables(path: str | PathLike[str] | None = None) -> dict[str, PaperTable]:
    """The tables of ``paper_tables.toml`` (or ``path``) by id (``table1`` .. ``table4``).

    Raises:
        TableSchemaError: the file breaks the schema; the message names table, row and column.
    """
    return dict(load_file(path).tables)


@cache
def _package_tables() -> Mapping[str, PaperTable]:
    return MappingProxyType(load_tables())


def table_ids() -> tuple[str, ...]:
    """The ids of the package's tables, in the file's order."""
    return tuple(_package_tables())


def table_numbers() -> dict[str, str]:
    """The package's tables by their roman numeral (``number``): ``{"I": "table1", ...}``."""
    return {t.number: tid for tid, t in _package_tables().items()}


def mapping_table_id(tables: Mapping[str, PaperTable] | None = None) -> str | None:
    """The id of the table whose rows are the mapping systems (``role = "mapping"``) among
    ``tables`` (default: the package's), or None where none of them is."""
    chosen = _package_tables() if tables is None else tables
    return next((tid for tid, t in chosen.items() if t.role == "mapping"), None)


def mapping_table(tables: Mapping[str, PaperTable] | None = None) -> PaperTable:
    """The table whose rows are the mapping systems, among ``tables`` (default: the
    package's).

    Raises:
        KeyError: none of ``tables`` is.
    """
    tid = mapping_table_id(tables)
    if tid is None:
        raise KeyError("no table has role 'mapping'")
    return (_package_tables() if tables is None else tables)[tid]


def load_file(path: str | PathLike[str] | None = None) -> PaperTables:
    """:func:`load_tables` with the ``[hardware]`` and ``[datasets]`` sections."""
    where = Path(path) if path is not None else default_path()
    try:
        with open(where, "rb") as f:
            data = tomllib.load(f)
    except OSError as exc:
        raise TableSchemaError(f"{where}: cannot read ({exc})") from None
    except UnicodeDecodeError as exc:
        raise TableSchemaError(f"{where}: not UTF-8 text ({exc})") from None
    except ValueError as exc:  # TOMLDecodeError, or an integer of more than 4300 digits
        raise TableSchemaError(f"{where}: not valid TOML ({exc})") from None
    except RecursionError:
        raise TableSchemaError(f"{where}: not valid TOML (nested too deeply)") from None
    return parse_tables(data, source=str(where))


def parse_tables(data: Mapping[str, Any], *, source: str = "paper tables") -> PaperTables:
    """Validate already-parsed TOML data (see :func:`load_tables`).

    Raises:
        TableSchemaError: ``source: place: what is wrong`` (one line).
    """
    try:
        model = validate(data, source=source)
    except TableSchemaError as exc:  # a key of the file may hold a line break: keep one line
        raise TableSchemaError(_one_line(str(exc))) from None
    return PaperTables(
        tables={tid: _table(tid, t) for tid, t in model.tables.items()},
        hardware={k: v.model_dump(exclude_unset=True) for k, v in model.hardware.items()},
        datasets={k: v.model_dump(exclude_unset=True) for k, v in model.datasets.items()},
        source=model.source)


def _one_line(text: str) -> str:
    """``text`` with line breaks and other unprintable characters escaped."""
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)


def _table(tid: str, raw: TableModel) -> PaperTable:
    columns = [c.record() for c in raw.columns]
    rows, cells = [], {}
    for r in raw.rows:
        system, row_cells = _row(tid, r, columns)
        rows.append(system)
        cells.update(row_cells)
    claims = tuple(c.record(tid, raw.baseline) for c in raw.claims if raw.baseline)
    return PaperTable(id=tid, number=raw.number, title=raw.title, caption=raw.caption,
                      columns=tuple(columns), rows=tuple(rows), cells=cells,
                      footnotes=dict(raw.footnotes), note=raw.note, role=raw.role,
                      baseline=raw.baseline, own_method=raw.own_method,
                      trained_beside=raw.trained_beside, claims=claims)


def _row(tid: str, raw: RowModel,
         columns: list[Column]) -> tuple[System, dict[tuple[str, str], Cell]]:
    seg, upd = raw.segmenter, raw.updater
    network = None if seg is None else SegmenterRef(card=seg.card, name=seg.name,
                                                     options=tuple(sorted(seg.options.items())))
    updater = None if upd is None else Component(upd.name, tuple(sorted(upd.options.items())))
    system = System(id=raw.id, label=raw.label, implemented=raw.implemented, network=network,
                    updater=updater, inputs=raw.inputs, year=raw.year, ablation=raw.ablation,
                    note=raw.note)
    cells = {}
    for col in columns:
        cell = raw.cells[col.id]
        cells[(raw.id, col.id)] = make_cell(tid, raw.id, col, cell.printed, bold=cell.bold,
                                            hardware=cell.hardware, note=cell.note)
    return system, cells
