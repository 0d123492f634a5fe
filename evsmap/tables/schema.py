"""The paper's tables as data: the schema of ``paper_tables.toml``, its loader and validator, and
the expansion of a table into runnable cells.

* :class:`PaperTable` - one printed table: its :class:`Column` s (metrics with unit, dataset,
  split and input or voxel size), its rows (:class:`System`: a segmenter and/or an updater
  configuration, or a paper-only network) and every printed :class:`Cell`.
* :func:`load_tables` reads and validates the file (unknown keys, a cell for an unknown row or
  column, a missing cell, a value that is not a number: a :class:`TableSchemaError` naming the
  table, row and column).
* :func:`expand` turns the implemented rows of a table into :class:`CellSpec` s: what one run
  measures (a system on one dataset or sequence at one resolution, a set of metrics), with a
  stable ``key`` and the requirements that may be missing (``needs``).

Values: :attr:`Cell.printed` is the text as printed ("4.5", "7.9†", "-"); :attr:`Cell.value` is
the number in base units (parameters, FLOPs, frames/s, Hz, bytes; MIoU as a fraction).
"""

from __future__ import annotations

import math
import re
import tomllib
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from importlib import resources
from os import PathLike
from pathlib import Path
from typing import Any

from evsmap.errors import DataFormatError

TABLES_FILE = "paper_tables.toml"
SCHEMA_VERSION = 1

BLANK = "-"
"""How a cell the paper leaves empty is written."""

CHECK = "√"
"""A ticked flag cell (Table III); an unticked one is the empty string."""

MARKS = ("†",)
"""Marks that may follow a printed number ("Testing on our experiment")."""

UNIT_SCALE: dict[str, float] = {"%": 0.01, "M": 1e6, "G": 1e9, "FPS": 1.0, "Hz": 1.0,
                                "B": 1.0, "KB": 1e3, "MB": 1e6, "GB": 1e9}
"""Printed unit -> factor to base units."""


@dataclass(frozen=True)
class Quantity:
    """What a column measures: the kind of run that measures it, its allowed printed units and
    base unit."""

    name: str
    kind: str
    units: tuple[str, ...]
    base_unit: str
    timing: bool = False


QUANTITIES: dict[str, Quantity] = {q.name: q for q in (
    Quantity("miou", "accuracy", ("%",), "fraction"),
    Quantity("params", "complexity", ("M",), "parameters"),
    Quantity("flops", "complexity", ("G",), "FLOPs"),
    Quantity("fps", "speed", ("FPS",), "frames/s", timing=True),
    Quantity("runtime_hz", "mapping", ("Hz",), "Hz", timing=True),
    Quantity("map_size", "mapping", ("B", "KB", "MB", "GB"), "bytes"),
    Quantity("flag", "flag", ("",), ""),
)}
"""The column quantities the tables use."""

KINDS = ("accuracy", "complexity", "speed", "mapping")
"""Kinds of runnable cells, in the order :func:`expand` lists a row's cells."""


class TableSchemaError(DataFormatError):
    """``paper_tables.toml`` (or a file given instead) does not follow the schema."""


# ------------------------------------------------------------------------------- records
@dataclass(frozen=True)
class Component:
    """A registered plug-in and its options (sorted ``(name, value)`` pairs, hashable)."""

    name: str
    options: tuple[tuple[str, Any], ...] = ()

    @property
    def config(self) -> dict[str, Any]:
        return dict(self.options)

    @property
    def spec(self) -> str:
        """``name`` or ``name(k=v,...)``: a stable string for keys and messages."""
        if not self.options:
            return self.name
        opts = ",".join(f"{k}={_fmt(v)}" for k, v in self.options)
        return f"{self.name}({opts})"

    def with_options(self, extra: Mapping[str, Any]) -> Component:
        merged = {**self.config, **extra}
        return Component(self.name, tuple(sorted(merged.items())))


def _fmt(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    return str(v)


@dataclass(frozen=True)
class Column:
    """One printed metric (or flag) column.

    Attributes:
        id: identifier used by the cells.
        header: the header as printed (multi-level headers joined).
        quantity: ``miou``, ``params``, ``flops``, ``fps``, ``runtime_hz``, ``map_size`` or
            ``flag``.
        unit: the printed unit (``%``, ``M``, ``G``, ``FPS``, ``Hz``, ``MB``; empty for flags).
        datasets: the dataset(s) or sequence(s) the column is measured on.
        split: the dataset split (``test``, ``val``), if any.
        input_size: network input ``(height, width)``, if the column depends on it.
        input_size_source: ``paper`` (printed) or ``assumed``.
        voxel_size: map resolution in metres (mapping columns).
        voxel_size_source: ``paper`` or ``assumed``.
        note: anything the paper leaves open about the column.
    """

    id: str
    header: str
    quantity: str
    unit: str = ""
    datasets: tuple[str, ...] = ()
    split: str | None = None
    input_size: tuple[int, int] | None = None
    input_size_source: str | None = None
    voxel_size: float | None = None
    voxel_size_source: str | None = None
    note: str = ""

    @property
    def kind(self) -> str:
        return QUANTITIES[self.quantity].kind

    @property
    def scale(self) -> float:
        return UNIT_SCALE.get(self.unit, 1.0)

    @property
    def base_unit(self) -> str:
        return QUANTITIES[self.quantity].base_unit

    @property
    def timing(self) -> bool:
        return QUANTITIES[self.quantity].timing


@dataclass(frozen=True)
class Cell:
    """One printed cell.

    Attributes:
        table, row, column: where it is.
        printed: the text as printed, without bold ("47.6", "7.9†", "-", "√", "").
        value: the number in base units (``printed number x unit``); ``None`` when blank; 1.0 /
            0.0 for a ticked / unticked flag.
        number: the printed number (``None`` when blank or a flag).
        decimals: digits after the decimal point as printed (``None`` when blank or a flag).
        unit: the column's printed unit.
        bold: printed in bold (the table's best value).
        marks: marks after the number (``"†"``: measured by the authors).
        hardware: where a speed was measured, when the paper says (a ``[hardware]`` id).
        note: a transcription remark.
    """

    table: str
    row: str
    column: str
    printed: str
    value: float | None
    number: float | None
    decimals: int | None
    unit: str = ""
    bold: bool = False
    marks: tuple[str, ...] = ()
    hardware: str | None = None
    note: str = ""

    @property
    def blank(self) -> bool:
        """The paper leaves this cell empty."""
        return self.printed == BLANK

    @property
    def text(self) -> str:
        """The cell as a reader sees it, number and unit with marks: "4.5M", "47.6%",
        "7.9 FPS†", "5.30 MB"; "-" when blank, the check mark for flags."""
        if self.number is None:
            return self.printed
        sep = " " if len(self.unit) > 1 else ""
        return f"{self.printed_number}{sep}{self.unit}{''.join(self.marks)}"

    @property
    def printed_number(self) -> str:
        return self.printed[: len(self.printed) - sum(len(m) for m in self.marks)]


@dataclass(frozen=True)
class System:
    """One row: a system of the paper.

    Attributes:
        id: identifier, unique in its table.
        label: the row label as printed ("FEAGNet-V1*", "MVSMMap").
        implemented: evsmap can run it (else the row prints as "paper only").
        segmenter, updater: the registered plug-ins and options that make up the system.
        dataset_options: segmenter option overrides per dataset (e.g. ``num_classes`` 37 on
            SUN RGB-D).
        inputs: ``rgb`` or ``rgbd`` where the table distinguishes them.
        year: the publication year printed as a subscript, for other authors' networks.
        ablation: the :data:`evsmap.models.feagnet.ABLATIONS` name of a Table III row.
        note: transcription remarks and assumptions.
    """

    id: str
    label: str
    implemented: bool
    segmenter: Component | None = None
    updater: Component | None = None
    dataset_options: tuple[tuple[str, tuple[tuple[str, Any], ...]], ...] = ()
    inputs: str | None = None
    year: int | None = None
    ablation: str | None = None
    note: str = ""

    def segmenter_for(self, dataset: str | None) -> Component | None:
        """The segmenter with the options for ``dataset`` applied."""
        if self.segmenter is None:
            return None
        extra = dict(dict(self.dataset_options).get(dataset, ()))
        return self.segmenter.with_options(extra) if extra else self.segmenter


@dataclass(frozen=True)
class PaperTable:
    """One table of the paper."""

    id: str
    number: str
    title: str
    caption: str
    columns: tuple[Column, ...]
    rows: tuple[System, ...]
    cells: Mapping[tuple[str, str], Cell] = field(repr=False)
    footnotes: Mapping[str, str] = field(default_factory=dict, repr=False)
    note: str = ""

    def column(self, column_id: str) -> Column:
        for c in self.columns:
            if c.id == column_id:
                return c
        raise KeyError(f"table {self.id}: no column {column_id!r}")

    def row(self, row_id: str) -> System:
        for r in self.rows:
            if r.id == row_id:
                return r
        raise KeyError(f"table {self.id}: no row {row_id!r}")

    def cell(self, row_id: str, column_id: str) -> Cell:
        try:
            return self.cells[(row_id, column_id)]
        except KeyError:
            raise KeyError(f"table {self.id}: no cell ({row_id!r}, {column_id!r})") from None


@dataclass(frozen=True)
class CellSpec:
    """One runnable measurement: a system, its data, its resolution and the metrics it yields.

    Attributes:
        key: stable unique identifier
            ``table/row/kind[/datasets[:split]][@WxH][@Rm][#hardware][quantities]``, e.g.
            ``table1/feagnet-v2/accuracy/nyuv2:test[miou]`` (for resume and caching).
        config_key: the same without table and row: runs with equal ``config_key`` measure the
            same thing (FEAGNet-V2's NYUv2 mIoU in Tables I and III).
        table, row, label: where the cell comes from.
        kind: ``accuracy``, ``complexity``, ``speed`` or ``mapping``.
        segmenter, updater: what to build (options applied for the dataset).
        datasets: datasets or sequences (empty for complexity and speed).
        split: dataset split, if any.
        input_size: network input ``(height, width)``, if fixed by the column.
        voxel_size: map resolution, metres (mapping cells).
        hardware: the ``[hardware]`` id the paper measured on, if stated.
        metrics: the column ids this run fills.
        paper: the printed cells of those columns.
        fresh_process: a timing measurement: run it in a fresh process.
        requires: everything the run needs beyond evsmap itself (``dataset:X``,
            ``weights:SEGMENTER@DATASET``, ``hardware:X``).
        needs: the part of ``requires`` not in the ``available`` set given to :func:`expand`.
    """

    key: str
    config_key: str
    table: str
    row: str
    label: str
    kind: str
    segmenter: Component | None
    updater: Component | None
    datasets: tuple[str, ...]
    split: str | None
    input_size: tuple[int, int] | None
    voxel_size: float | None
    hardware: str | None
    metrics: tuple[str, ...]
    paper: tuple[Cell, ...] = field(repr=False)
    fresh_process: bool
    requires: tuple[str, ...]
    needs: tuple[str, ...]

    @property
    def resolution(self) -> str | None:
        """``WxH`` input size or ``R m`` voxel size, as the paper prints it."""
        if self.input_size is not None:
            return f"{self.input_size[1]}x{self.input_size[0]}"
        if self.voxel_size is not None:
            return f"{self.voxel_size:g} m"
        return None

    @property
    def runnable(self) -> bool:
        """Nothing required is missing."""
        return not self.needs


# ------------------------------------------------------------------------------- loading
_TOP_KEYS = {"schema_version", "source", "hardware", "datasets", "tables"}
_HARDWARE_KEYS = {"description", "note"}
_DATASET_KEYS = {"description", "inferred"}
_TABLE_KEYS = {"number", "title", "caption", "footnotes", "note", "columns", "rows"}
_COLUMN_KEYS = {"id", "header", "quantity", "unit", "dataset", "split", "input_size",
                "input_size_source", "voxel_size", "voxel_size_source", "note"}
_ROW_KEYS = {"id", "label", "implemented", "segmenter", "updater", "dataset_options", "inputs",
             "year", "ablation", "note", "cells"}
_COMPONENT_KEYS = {"name", "options"}
_CELL_KEYS = {"printed", "bold", "hardware", "note"}
_SOURCES = ("paper", "assumed")
_NUMBER = re.compile(r"^(\d+)(?:\.(\d+))?$")
_ID = re.compile(r"^[a-z0-9][a-z0-9_.+-]*$")


@dataclass(frozen=True)
class PaperTables:
    """Everything in the file: tables by id, hardware and datasets descriptions."""

    tables: Mapping[str, PaperTable]
    hardware: Mapping[str, Mapping[str, Any]]
    datasets: Mapping[str, Mapping[str, Any]]
    source: str = ""


def default_path() -> Path:
    return Path(str(resources.files("evsmap.tables").joinpath(TABLES_FILE)))


def load_tables(path: str | PathLike[str] | None = None) -> dict[str, PaperTable]:
    """The tables of ``paper_tables.toml`` (or ``path``) by id (``table1`` .. ``table4``).

    Raises:
        TableSchemaError: the file breaks the schema; the message names table, row and column.
    """
    return dict(load_file(path).tables)


def load_file(path: str | PathLike[str] | None = None) -> PaperTables:
    """:func:`load_tables` with the ``[hardware]`` and ``[datasets]`` sections."""
    where = Path(path) if path is not None else default_path()
    try:
        with open(where, "rb") as f:
            data = tomllib.load(f)
    except OSError as exc:
        raise TableSchemaError(f"{where}: cannot read ({exc})") from None
    except tomllib.TOMLDecodeError as exc:
        raise TableSchemaError(f"{where}: not valid TOML ({exc})") from None
    return parse_tables(data, source=str(where))


def parse_tables(data: Mapping[str, Any], *, source: str = "paper tables") -> PaperTables:
    """Validate already-parsed TOML data (see :func:`load_tables`)."""
    _keys(data, _TOP_KEYS, source)
    if data.get("schema_version") != SCHEMA_VERSION:
        raise TableSchemaError(f"{source}: schema_version must be {SCHEMA_VERSION}, got "
                               f"{data.get('schema_version')!r}")
    hardware = _mapping(data.get("hardware", {}), f"{source}: [hardware]")
    for hw, spec in hardware.items():
        _keys(_mapping(spec, f"hardware {hw!r}"), _HARDWARE_KEYS, f"hardware {hw!r}")
    datasets = _mapping(data.get("datasets", {}), f"{source}: [datasets]")
    for ds, spec in datasets.items():
        _keys(_mapping(spec, f"dataset {ds!r}"), _DATASET_KEYS, f"dataset {ds!r}")
    tables_raw = _mapping(data.get("tables"), f"{source}: [tables]")
    if not tables_raw:
        raise TableSchemaError(f"{source}: no [tables]")
    tables = {tid: _parse_table(tid, raw, set(hardware), set(datasets))
              for tid, raw in tables_raw.items()}
    return PaperTables(tables=tables, hardware=hardware, datasets=datasets,
                       source=str(data.get("source", "")))


def _mapping(value: Any, where: str) -> dict:
    if not isinstance(value, dict):
        raise TableSchemaError(f"{where}: expected a table, got {type(value).__name__}")
    return value


def _keys(d: Mapping[str, Any], allowed: set[str], where: str) -> None:
    unknown = sorted(set(d) - allowed)
    if unknown:
        raise TableSchemaError(f"{where}: unknown key(s) {', '.join(map(repr, unknown))} "
                               f"(allowed: {', '.join(sorted(allowed))})")


def _str(d: Mapping[str, Any], key: str, where: str, *, required: bool = True,
         default: str = "") -> str:
    if key not in d:
        if required:
            raise TableSchemaError(f"{where}: missing {key!r}")
        return default
    v = d[key]
    if not isinstance(v, str):
        raise TableSchemaError(f"{where}: {key!r} must be a string, got {v!r}")
    return v


def _parse_table(tid: str, raw: Any, hardware: set[str], datasets: set[str]) -> PaperTable:
    where = f"table {tid}"
    raw = _mapping(raw, where)
    _keys(raw, _TABLE_KEYS, where)
    columns = [_parse_column(tid, c, datasets) for c in raw.get("columns", [])]
    if not columns:
        raise TableSchemaError(f"{where}: no columns")
    _unique([c.id for c in columns], f"{where}: column")
    col_by_id = {c.id: c for c in columns}
    rows, cells = [], {}
    for r in raw.get("rows", []):
        system, row_cells = _parse_row(tid, r, col_by_id, hardware, datasets)
        rows.append(system)
        cells.update(row_cells)
    if not rows:
        raise TableSchemaError(f"{where}: no rows")
    _unique([r.id for r in rows], f"{where}: row")
    footnotes = _mapping(raw.get("footnotes", {}), f"{where}: footnotes")
    return PaperTable(id=tid, number=_str(raw, "number", where),
                      title=_str(raw, "title", where),
                      caption=_str(raw, "caption", where, required=False),
                      columns=tuple(columns), rows=tuple(rows), cells=cells,
                      footnotes=dict(footnotes), note=_str(raw, "note", where, required=False))


def _unique(ids: list[str], what: str) -> None:
    seen = set()
    for i in ids:
        if i in seen:
            raise TableSchemaError(f"{what} id {i!r} appears twice")
        seen.add(i)


def _parse_column(tid: str, raw: Any, datasets: set[str]) -> Column:
    raw = _mapping(raw, f"table {tid}: column")
    cid = _str(raw, "id", f"table {tid}: a column")
    where = f"table {tid}, column {cid!r}"
    if not _ID.match(cid):
        raise TableSchemaError(f"{where}: ids are lower case letters, digits and _.+-")
    _keys(raw, _COLUMN_KEYS, where)
    quantity = _str(raw, "quantity", where)
    if quantity not in QUANTITIES:
        raise TableSchemaError(f"{where}: unknown quantity {quantity!r} (known: "
                               f"{', '.join(QUANTITIES)})")
    q = QUANTITIES[quantity]
    unit = _str(raw, "unit", where, required=False)
    if unit not in q.units:
        raise TableSchemaError(f"{where}: unit {unit!r} does not fit quantity {quantity!r} "
                               f"(allowed: {', '.join(map(repr, q.units))})")
    ds = raw.get("dataset", [])
    ds = [ds] if isinstance(ds, str) else ds
    if not isinstance(ds, list) or not all(isinstance(x, str) for x in ds):
        raise TableSchemaError(f"{where}: dataset must be a name or a list of names")
    for d in ds:
        if d not in datasets:
            raise TableSchemaError(f"{where}: unknown dataset {d!r} (declared: "
                                   f"{', '.join(sorted(datasets))})")
    if q.kind in ("accuracy", "mapping") and not ds:
        raise TableSchemaError(f"{where}: a {quantity} column needs a dataset")
    size = raw.get("input_size")
    if size is not None:
        if not (isinstance(size, list) and len(size) == 2
                and all(isinstance(s, int) and not isinstance(s, bool) and s > 0 for s in size)):
            raise TableSchemaError(f"{where}: input_size must be [height, width], got {size!r}")
        size = (size[0], size[1])
    voxel = raw.get("voxel_size")
    if voxel is not None and (isinstance(voxel, bool) or not isinstance(voxel, (int, float))
                              or not voxel > 0):
        raise TableSchemaError(f"{where}: voxel_size must be a positive number of metres")
    for key, value in (("input_size_source", size), ("voxel_size_source", voxel)):
        src = raw.get(key)
        if (value is None) != (src is None):
            raise TableSchemaError(f"{where}: give {key} exactly when "
                                   f"{key.removesuffix('_source')} is given")
        if src is not None and src not in _SOURCES:
            raise TableSchemaError(f"{where}: {key} must be one of {_SOURCES}, got {src!r}")
    return Column(id=cid, header=_str(raw, "header", where), quantity=quantity, unit=unit,
                  datasets=tuple(ds), split=raw.get("split"), input_size=size,
                  input_size_source=raw.get("input_size_source"),
                  voxel_size=None if voxel is None else float(voxel),
                  voxel_size_source=raw.get("voxel_size_source"),
                  note=_str(raw, "note", where, required=False))


def _component(raw: Any, where: str) -> Component | None:
    if raw is None:
        return None
    raw = _mapping(raw, where)
    _keys(raw, _COMPONENT_KEYS, where)
    name = _str(raw, "name", where)
    opts = _mapping(raw.get("options", {}), f"{where} options")
    return Component(name, tuple(sorted(opts.items())))


def _parse_row(tid: str, raw: Any, columns: dict[str, Column], hardware: set[str],
               datasets: set[str]) -> tuple[System, dict[tuple[str, str], Cell]]:
    raw = _mapping(raw, f"table {tid}: row")
    rid = _str(raw, "id", f"table {tid}: a row")
    where = f"table {tid}, row {rid!r}"
    if not _ID.match(rid):
        raise TableSchemaError(f"{where}: ids are lower case letters, digits and _.+-")
    _keys(raw, _ROW_KEYS, where)
    implemented = raw.get("implemented")
    if not isinstance(implemented, bool):
        raise TableSchemaError(f"{where}: 'implemented' must be true or false")
    segmenter = _component(raw.get("segmenter"), f"{where}: segmenter")
    updater = _component(raw.get("updater"), f"{where}: updater")
    if implemented and segmenter is None and updater is None:
        raise TableSchemaError(f"{where}: an implemented row needs a segmenter or an updater")
    per_ds = _mapping(raw.get("dataset_options", {}), f"{where}: dataset_options")
    for d, opts in per_ds.items():
        if d not in datasets:
            raise TableSchemaError(f"{where}: dataset_options for unknown dataset {d!r}")
        _mapping(opts, f"{where}: dataset_options.{d}")
    year = raw.get("year")
    if year is not None and (isinstance(year, bool) or not isinstance(year, int)):
        raise TableSchemaError(f"{where}: year must be an integer")
    system = System(
        id=rid, label=_str(raw, "label", where), implemented=implemented, segmenter=segmenter,
        updater=updater,
        dataset_options=tuple(sorted((d, tuple(sorted(o.items()))) for d, o in per_ds.items())),
        inputs=raw.get("inputs"), year=year, ablation=raw.get("ablation"),
        note=_str(raw, "note", where, required=False))
    cells_raw = _mapping(raw.get("cells", {}), f"{where}: cells")
    for cid in cells_raw:
        if cid not in columns:
            raise TableSchemaError(f"table {tid}, row {rid!r}, column {cid!r}: no such column "
                                   f"(columns: {', '.join(columns)})")
    cells = {}
    for cid, col in columns.items():
        if cid not in cells_raw:
            raise TableSchemaError(f"table {tid}, row {rid!r}, column {cid!r}: cell missing "
                                   f"(write \"{BLANK}\" for a cell the paper leaves blank)")
        cells[(rid, cid)] = _parse_cell(tid, rid, col, cells_raw[cid], hardware)
    return system, cells


def _parse_cell(tid: str, rid: str, col: Column, raw: Any, hardware: set[str]) -> Cell:
    where = f"table {tid}, row {rid!r}, column {col.id!r}"
    extra: dict[str, Any] = {}
    if isinstance(raw, dict):
        _keys(raw, _CELL_KEYS, where)
        printed = _str(raw, "printed", where)
        extra = {k: raw[k] for k in ("bold", "hardware", "note") if k in raw}
        if not isinstance(extra.get("bold", False), bool):
            raise TableSchemaError(f"{where}: bold must be true or false")
        hw = extra.get("hardware")
        if hw is not None and hw not in hardware:
            raise TableSchemaError(f"{where}: unknown hardware {hw!r} (declared: "
                                   f"{', '.join(sorted(hardware)) or 'none'})")
        if hw is not None and not col.timing:
            raise TableSchemaError(f"{where}: hardware applies to timing columns only")
    elif isinstance(raw, str):
        printed = raw
    else:
        raise TableSchemaError(f"{where}: a cell is a printed string or an inline table, got "
                               f"{raw!r}")
    base = dict(table=tid, row=rid, column=col.id, printed=printed, unit=col.unit,
                bold=bool(extra.get("bold", False)), hardware=extra.get("hardware"),
                note=str(extra.get("note", "")))
    if col.quantity == "flag":
        if printed not in (CHECK, ""):
            raise TableSchemaError(f"{where}: a flag cell is {CHECK!r} or '', got {printed!r}")
        return Cell(value=1.0 if printed == CHECK else 0.0, number=None, decimals=None, **base)
    if printed == BLANK:
        return Cell(value=None, number=None, decimals=None, **base)
    text, marks = printed, []
    while text and any(text.endswith(m) for m in MARKS):
        mark = next(m for m in MARKS if text.endswith(m))
        marks.insert(0, mark)
        text = text[: -len(mark)]
    if col.unit and text.endswith(col.unit) and col.unit != "%":
        text = text[: -len(col.unit)]  # "4.5M" written with its unit
    match = _NUMBER.match(text)
    if not match:
        raise TableSchemaError(f"{where}: {printed!r} is not a number (write \"{BLANK}\" for a "
                               f"blank cell)")
    number = float(text)
    if not math.isfinite(number):  # pragma: no cover - the pattern only admits digits
        raise TableSchemaError(f"{where}: {printed!r} is not finite")
    base["printed"] = text + "".join(marks)
    return Cell(value=number * col.scale, number=number,
                decimals=len(match.group(2) or ""), marks=tuple(marks), **base)


# ------------------------------------------------------------------------------- expansion
def _requirements(kind: str, segmenter: Component | None, datasets: tuple[str, ...],
                  hardware: str | None, weights_dataset: str | None) -> tuple[str, ...]:
    req = []
    if kind in ("accuracy", "mapping"):
        req += [f"dataset:{d}" for d in datasets]
        if segmenter is not None and segmenter.name != "oracle":
            req.append(f"weights:{segmenter.spec}@{weights_dataset}")
    if hardware is not None:
        req.append(f"hardware:{hardware}")
    return tuple(sorted(set(req)))


def _groups(table: PaperTable, system: System) -> list[tuple[list[Column], str | None]]:
    """A row's measured columns grouped into runs, ordered by :data:`KINDS`, then by first
    column. Columns of one kind go together when they share datasets, split, input and voxel
    size, hardware and timing; a complexity column without an input size (parameters) joins
    the row's first complexity run."""
    groups: dict[tuple, list[Column]] = {}
    loose: list[Column] = []
    for col in table.columns:
        if col.kind == "flag" or (col.kind != "mapping" and system.segmenter is None):
            continue  # flags are settings; an updater-only system has no network to score
        hw = table.cell(system.id, col.id).hardware
        if col.kind == "complexity" and col.input_size is None:
            loose.append(col)
            continue
        key = (col.kind, col.datasets, col.split, col.input_size, col.voxel_size, hw,
               col.timing)
        groups.setdefault(key, []).append(col)
    if loose:
        target = next((k for k in groups if k[0] == "complexity"), None)
        if target is None:
            groups[("complexity", (), None, None, None, None, False)] = loose
        else:
            groups[target] = sorted(loose + groups[target], key=table.columns.index)
    ordered = sorted(groups.items(), key=lambda kv: KINDS.index(kv[0][0]))  # stable sort
    return [(cols, key[5]) for key, cols in ordered]


def expand(table: PaperTable, *, available: Iterable[str] | None = None,
           mapping_weights: str = "nyuv2") -> list[CellSpec]:
    """The runnable cells of ``table``'s implemented rows, in row order and, within a row, by
    kind (accuracy, complexity, speed, mapping) and then column order.

    A row's columns of one kind that share datasets, split, input and voxel size and hardware
    make one cell (Table I's params and FLOPs are one complexity run). Paper-only rows
    (``implemented = false``) are skipped; flags are not measured.

    Args:
        available: requirement strings that are satisfied (``"dataset:nyuv2"``,
            ``"weights:feagnet-v2@nyuv2"``, ``"hardware:jetson-tensorrt"``); what a cell
            requires beyond them is its ``needs``. ``None``: nothing is assumed available.
        mapping_weights: the dataset the segmenters of mapping systems are trained on (the
            paper does not say; NYUv2's 40 classes).
    """
    have = frozenset(available or ())
    out: list[CellSpec] = []
    for system in table.rows:
        if not system.implemented:
            continue
        for cols, hw in _groups(table, system):
            first = cols[0]
            kind, datasets, split = first.kind, first.datasets, first.split
            size = next((c.input_size for c in cols if c.input_size is not None), None)
            voxel = first.voxel_size
            timing = first.timing
            if kind == "mapping":
                segmenter = system.segmenter_for(mapping_weights)
                weights_ds = mapping_weights
            else:
                weights_ds = datasets[0] if kind == "accuracy" else None
                segmenter = system.segmenter_for(weights_ds)
            requires = _requirements(kind, segmenter, datasets, hw, weights_ds)
            what = kind
            if datasets:
                what += "/" + "+".join(datasets) + (f":{split}" if split else "")
            if size is not None:
                what += f"@{size[1]}x{size[0]}"
            if voxel is not None:
                what += f"@{voxel:g}m"
            if hw is not None:
                what += f"#{hw}"
            what += "[" + ",".join(c.quantity for c in cols) + "]"
            systems = "+".join(c.spec for c in (segmenter, system.updater) if c is not None)
            out.append(CellSpec(
                key=f"{table.id}/{system.id}/{what}", config_key=f"{systems}/{what}",
                table=table.id, row=system.id, label=system.label, kind=kind,
                segmenter=segmenter, updater=system.updater, datasets=datasets, split=split,
                input_size=size, voxel_size=voxel, hardware=hw,
                metrics=tuple(c.id for c in cols),
                paper=tuple(table.cell(system.id, c.id) for c in cols),
                fresh_process=timing, requires=requires,
                needs=tuple(r for r in requires if r not in have)))
    keys = [c.key for c in out]
    if len(set(keys)) != len(keys):  # pragma: no cover - guarded by the tests
        raise TableSchemaError(f"table {table.id}: expansion produced duplicate keys")
    return out


def expand_all(tables: Mapping[str, PaperTable] | None = None, *,
               available: Iterable[str] | None = None) -> list[CellSpec]:
    """:func:`expand` over every table (all of :func:`load_tables` by default), in id order."""
    tables = load_tables() if tables is None else tables
    have = None if available is None else list(available)
    return [spec for tid in sorted(tables) for spec in expand(tables[tid], available=have)]
