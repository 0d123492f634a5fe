"""The records of the paper tables: what :func:`evsmap.tables.load_tables` returns.

* :class:`PaperTable` - one printed table: its :class:`Column` s (metrics with unit, dataset,
  split and input or voxel size), its rows (:class:`System`) and every printed :class:`Cell`.
* :class:`System` - one row: a segmenter (a model card, :mod:`evsmap.segmenters.model_card`, or a
  registered name, with options) and/or an updater, or a paper-only network.
* :class:`Component` - a registered plug-in with its options, as a run builds it.
* :data:`QUANTITIES` - what a column may measure, in which printed units.

Values: :attr:`Cell.printed` is the text as printed ("4.5", "7.9†", "-"); :attr:`Cell.value` is
the number in base units (parameters, FLOPs, frames/s, Hz, bytes; MIoU as a fraction).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
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
        resolution: map resolution in metres (mapping columns).
        resolution_source: ``paper`` or ``assumed``.
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
    resolution: float | None = None
    resolution_source: str | None = None
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
class SegmenterRef:
    """A row's network as the file names it: a model ``card`` (the network for a label set,
    resolved per dataset) or a registered segmenter ``name``, plus ``options`` on top (Table
    III's ablation switches)."""

    card: str | None = None
    name: str | None = None
    options: tuple[tuple[str, Any], ...] = ()

    def resolve(self, dataset: str | None) -> Component:
        """The segmenter that runs on ``dataset`` (``None``: no dataset, e.g. complexity): a
        card's segmenter with the options of its card for that dataset's label set
        (:meth:`evsmap.segmenters.model_card.CardRegistry.for_dataset`), then :attr:`options`.

        Raises:
            UnknownNameError: no card of that name (with the closest one).
        """
        if self.card is None:
            return Component(str(self.name), self.options)
        from evsmap.segmenters.model_card import MODEL_CARDS

        card = MODEL_CARDS.for_dataset(self.card, dataset)
        return Component(card.segmenter, card.options).with_options(dict(self.options))


@dataclass(frozen=True)
class System:
    """One row: a system of the paper.

    Attributes:
        id: identifier, unique in its table.
        label: the row label as printed ("FEAGNet-V1*", "MVSMMap").
        implemented: evsmap can run it (else the row prints as "paper only").
        network: the segmenter as the file names it (a model card or a name, with options).
        updater: the registered map updater and its options.
        inputs: ``rgb`` or ``rgbd`` where the table distinguishes them.
        year: the publication year printed as a subscript, for other authors' networks.
        ablation: the :data:`evsmap.models.feagnet.ABLATIONS` name of a Table III row.
        note: transcription remarks and assumptions.
    """

    id: str
    label: str
    implemented: bool
    network: SegmenterRef | None = None
    updater: Component | None = None
    inputs: str | None = None
    year: int | None = None
    ablation: str | None = None
    note: str = ""

    @property
    def segmenter(self) -> Component | None:
        """The segmenter where no dataset is involved (the row's card as named)."""
        return self.segmenter_for(None)

    def segmenter_for(self, dataset: str | None) -> Component | None:
        """The segmenter that runs on ``dataset``: the row's card for that dataset's label set
        (:meth:`SegmenterRef.resolve`)."""
        return None if self.network is None else self.network.resolve(dataset)


@dataclass(frozen=True)
class Claim:
    """A comparative claim of the paper about ``value(row, column) / value(base, column)``:
    above 1 (``mode="higher"``), below 1 (``"lower"``), or within
    :data:`evsmap.tables.claims.MATCH_TOLERANCE` of the paper's own ratio (``"match"``: the
    paper trades accuracy for speed, so what it claims is its relative accuracy, not a win)."""

    text: str
    table: str
    row: str
    base: str
    column: str
    mode: str


@dataclass(frozen=True)
class PaperTable:
    """One table of the paper, and what it is: ``number`` (its roman numeral, as
    ``reproduce --tables`` names it); ``role`` ("networks", "ablation" or "mapping": the one
    table whose rows are mapping systems); ``baseline`` (the row the paper sets its method
    against); ``own_method`` (every row is the paper's method: measured first);
    ``trained_beside`` (``reproduce --train``'s networks are shown beside it); ``claims``."""

    id: str
    number: str
    title: str
    caption: str
    columns: tuple[Column, ...]
    rows: tuple[System, ...]
    cells: Mapping[tuple[str, str], Cell] = field(repr=False)
    footnotes: Mapping[str, str] = field(default_factory=dict, repr=False)
    note: str = ""
    role: str = "networks"
    baseline: str | None = None
    own_method: bool = False
    trained_beside: bool = False
    claims: tuple[Claim, ...] = ()

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
class PaperTables:
    """Everything in the file: tables by id, hardware and datasets descriptions."""

    tables: Mapping[str, PaperTable]
    hardware: Mapping[str, Mapping[str, Any]]
    datasets: Mapping[str, Mapping[str, Any]]
    source: str = ""
