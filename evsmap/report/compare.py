"""Runs side by side: the cells they share, each with its precision, and their ratios.

:func:`compare_runs` reads two or more run folders (:func:`~evsmap.report.run_data.load_run`),
or the paper as a pseudo-run named :data:`PAPER`, into a :class:`Comparison`:

* every measured cell of each run: the paper's Tables I-IV (in the tables' printed units) and
  the mapping runs beyond them (``extra``: rates, sizes, counts and scores per sequence);
* a timed value (a speed or a rate) carries its precision, the relative half-width of its
  median's 95 % interval (the timing policy's, as ``index.md``'s "Timing precision" states it);
  a count, a size or a score is exact;
* each shared cell's ratio to the first column (run B / run A), a timed ratio with its own
  precision: the two relative half-widths added (:func:`ratio_precision`), an exact one read as
  ``equal`` or ``differ``;
* the cells that only some of the runs measured, apart.

The paper's column holds its printed figures; their precision is what their printed digits
say (half a unit of the last digit, relative): a measured count equals the paper's when it
rounds to the printed figure. :mod:`evsmap.report.compare_text` prints a comparison (Markdown,
CSV, JSON), :mod:`evsmap.report.compare_plot` draws its speed cells and
:mod:`evsmap.report.latex` writes it as LaTeX.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from evsmap.errors import DataFormatError
from evsmap.report.cells import number
from evsmap.report.extra import EXTRA_PRINT
from evsmap.report.run_data import LoadedRun, commit_of, gpu_of, load_run, machine_text
from evsmap.runner.records import CellRecord
from evsmap.runner.runfile import RUN_FILE

PAPER = "paper"
"""The name that stands for the paper's printed figures in :func:`compare_runs`."""

TIMED_UNITS = ("FPS", "Hz")
"""Units of the timed cells (the others are counts, sizes and scores: exact)."""

EXTRA_TIMED = ("update_hz", "segment_update_hz")
"""The mapping runs' timed values; ``segment_update_hz`` carries its precision (the record's
``rel_ci``), ``update_hz`` none."""

EXACT_REL = 1e-12
"""Two exact values are ``equal`` when they differ by no more than this share (the rounding of
one division to a printed unit); anything more is a difference."""


@dataclass(frozen=True)
class Cell:
    """What a cell is: its table (``table1``..``table4``, ``extra``), row and column, and the
    words and unit a reader sees."""

    table: str
    row: str
    column: str
    label: str
    header: str
    unit: str
    timed: bool

    @property
    def id(self) -> str:
        return f"{self.table}/{self.row}/{self.column}"

    @property
    def speed(self) -> bool:
        """A network's speed (a point of the speed plot)."""
        return self.unit == "FPS"


@dataclass(frozen=True)
class Value:
    """One column's figure for a cell: ``rel`` its relative half-width (None: exact, or a
    timing without one); ``decimals`` the digits the paper printed (the paper's column only);
    ``flag`` a flagged timing's reason."""

    value: float
    rel: float | None = None
    decimals: int | None = None
    flag: str | None = None


@dataclass
class Column:
    """One run (or the paper) in a comparison: its name, where it was read, its machine (in
    words, its machine kind id where known, its environment record) and commit, and its
    measured cells and their values by :attr:`Cell.id`."""

    name: str
    path: str | None
    machine: str
    commit: str
    quick: bool | None = None
    started: str = ""
    gpu: str | None = None
    kind: str | None = None
    environment: dict[str, Any] = field(default_factory=dict)
    timing: str = "-"
    values: dict[str, Value] = field(default_factory=dict)
    cells: dict[str, Cell] = field(default_factory=dict)

    def add(self, cell: Cell, value: Value) -> None:
        self.cells[cell.id] = cell
        self.values[cell.id] = value

    @property
    def is_paper(self) -> bool:
        return self.path is None


@dataclass(frozen=True)
class Ratio:
    """Column ``i`` / the first column for one cell: the ratio, its relative half-width (a
    timed cell's; None when a side has none), and ``verdict``: ``equal`` / ``differ`` for an
    exact cell, ``within precision`` / ``differs`` / ``no precision`` for a timed one."""

    ratio: float | None
    rel: float | None
    verdict: str


@dataclass
class Comparison:
    """Two or more columns, the cells they all measured (``shared``, in table order) with each
    column's ratio to the first, and the cells only some measured (``apart``)."""

    columns: list[Column]
    cells: dict[str, Cell]
    shared: list[str]
    apart: list[str]
    ratios: dict[str, list[Ratio]]


# ------------------------------------------------------------------------------- columns
def run_column(loaded: LoadedRun, name: str | None = None) -> Column:
    """A run's measured cells as a comparison column."""
    run = loaded.run
    column = Column(name=name or loaded.path.name, path=str(loaded.path),
                    machine=machine_text(run), commit=commit_of(run),
                    quick=bool(run.get("quick")), started=str(run.get("started") or ""),
                    gpu=gpu_of(run), environment=loaded.environment,
                    timing=timing_text(run.get("context") or {}))
    for cell, value in [*table_values(loaded), *extra_values(loaded.extras)]:
        column.add(cell, value)
    return column


def timing_text(context: Mapping[str, Any]) -> str:
    """How a run timed its speed cells: ``onnxruntime, 2 threads, target +-3 %, 10 s`` (two
    runs timed otherwise differ by more than the machine)."""
    policy = context.get("timing") or {}
    parts = [str(context.get("speed_backend") or "?"), f"{context.get('threads') or '?'} threads"]
    if isinstance(policy, Mapping) and policy.get("target_rel_ci") is not None:
        parts.append(f"target +-{100 * float(policy['target_rel_ci']):g} %, "
                     f"{float(policy.get('budget_s') or 0):g} s")
    return ", ".join(parts)


def paper_column(loaded: LoadedRun) -> Column:
    """The paper's printed figures of the tables ``loaded`` covers, as a column."""
    column = Column(name=PAPER, path=None, machine="the paper's (GPU or Jetson, per table)",
                    commit="-")
    for tid in loaded.table_ids:
        table = loaded.tables[tid]
        for line in loaded.frames[tid].to_dict("records"):
            paper = number(line.get("paper"))
            if paper is None:
                continue
            printed = table.cell(line["row"], line["column"])
            column.add(_table_cell(line), Value(
                paper, rel=printed_precision(paper, printed.decimals),
                decimals=printed.decimals))
    return column


def printed_precision(value: float, decimals: int | None) -> float | None:
    """Half a unit of a printed figure's last digit, relative to it: the precision of a figure
    known only as printed (``4.5`` printed with one decimal: 0.05 / 4.5)."""
    if decimals is None or value == 0:
        return None
    return 0.5 * 10.0 ** -decimals / abs(value)


def _table_cell(line: Mapping[str, Any]) -> Cell:
    unit = str(line.get("unit") or "")
    header = str(line.get("header") or line["column"])
    if unit and unit not in header:
        header = f"{header} ({unit})"
    return Cell(table=str(line["table"]), row=str(line["row"]), column=str(line["column"]),
                label=str(line.get("label") or line["row"]), header=header, unit=unit,
                timed=unit in TIMED_UNITS)


def table_values(loaded: LoadedRun) -> list[tuple[Cell, Value]]:
    """Every measured (``ok``) cell of the run's tables, in table order, in printed units."""
    out = []
    for tid in loaded.table_ids:
        for line in loaded.frames[tid].to_dict("records"):
            measured = number(line.get("measured"))
            if line.get("status") != "ok" or measured is None:
                continue
            cell = _table_cell(line)
            flag = line.get("timing_flag")
            out.append((cell, Value(measured, rel=number(line.get("rel_ci")) if cell.timed
                                    else None,
                                    flag=flag if isinstance(flag, str) and flag else None)))
    return out


def extra_values(extras: Sequence[CellRecord]) -> list[tuple[Cell, Value]]:
    """Every value of the mapping runs beyond the tables (one cell per run and quantity of
    :data:`~evsmap.report.extra.EXTRA_PRINT`, in its printed unit)."""
    out = []
    for rec in extras:
        if rec.status != "ok" or not rec.key.startswith("extra/mapping/"):
            continue
        where = _where(rec)
        for key, header, divisor, _ in EXTRA_PRINT:
            value = number(rec.values.get(key))
            if value is None:
                continue
            timed = key in EXTRA_TIMED
            rel = number((rec.details or {}).get("rel_ci")) if key == "segment_update_hz" \
                else None
            flag = (rec.details or {}).get("timing_flag") if timed else None
            unit = "Hz" if timed else header.rsplit("(", 1)[-1].rstrip(")") \
                if header.endswith(")") else ""
            cell = Cell(table="extra", row=rec.key.removeprefix("extra/mapping/"), column=key,
                        label=f"{rec.label or rec.row}, {where}", header=header, unit=unit,
                        timed=timed)
            out.append((cell, Value(value / divisor, rel=rel,
                                    flag=flag if isinstance(flag, str) and flag else None)))
    return out


def _where(rec: CellRecord) -> str:
    seq = str(rec.inputs.get("sequence") or "?")
    voxel = number(rec.inputs.get("resolution"))
    return seq if voxel is None else f"{seq} at {voxel * 100:g} cm"


# ------------------------------------------------------------------------------- ratios
def ratio_precision(a: Value, b: Value) -> float | None:
    """The relative half-width of ``b / a``: the two relative half-widths added (to first
    order, the ratio's interval is as wide as both of its terms' together; each term moves
    independently, so adding them bounds what quadrature would give). None when a side has
    none."""
    if a.rel is None or b.rel is None:
        return None
    return a.rel + b.rel


def compare_values(cell: Cell, a: Value, b: Value, *, paper: bool) -> Ratio:
    """``b`` against ``a`` for one cell (``paper``: one side is the paper's printed figure)."""
    ratio = b.value / a.value if a.value else None
    if cell.timed:
        rel = ratio_precision(a, b)
        if ratio is None or rel is None:
            return Ratio(ratio, rel, "no precision")
        return Ratio(ratio, rel, "within precision" if abs(ratio - 1.0) <= rel else "differs")
    return Ratio(ratio, None, "equal" if _equal(a, b, paper=paper) else "differ")


def _equal(a: Value, b: Value, *, paper: bool) -> bool:
    if paper:  # a measured figure equals the paper's when it rounds to what was printed
        printed = a if a.decimals is not None else b
        other = b if printed is a else a
        if printed.decimals is not None:
            return round(other.value, printed.decimals) == round(printed.value,
                                                                 printed.decimals)
    scale = max(abs(a.value), abs(b.value))
    return abs(a.value - b.value) <= EXACT_REL * scale


# ------------------------------------------------------------------------------- building
def read_columns(names: Sequence[str | Path], *, paper: bool = False) -> list[Column]:
    """The columns of ``names`` (run folders, or :data:`PAPER`), in order; ``paper``: the
    paper's column added last (unless named).

    Raises:
        DataFormatError: fewer than two columns, a name that is no run folder, or a run read
            twice (one line naming the path).
    """
    wanted = [str(n) for n in names]
    if paper and PAPER not in wanted:
        wanted.append(PAPER)
    if len(wanted) < 2:
        given = wanted[0] if wanted else "nothing"
        raise DataFormatError(f"{given}: a comparison needs two runs or more (give another run "
                              f"folder, or --paper to set the paper beside it)")
    loaded: dict[str, LoadedRun] = {}
    for name in wanted:
        if name == PAPER:
            continue
        path = Path(name)
        if not (path / RUN_FILE).is_file():
            what = "no such folder" if not path.exists() else "not a run folder (no run.json)"
            raise DataFormatError(f"{path}: {what}; give folders that `evsmap reproduce` wrote "
                                  f"(reports/<run>, results/<run>)")
        key = str(path.resolve())
        if key in loaded:
            raise DataFormatError(f"{path}: given twice; compare different runs")
        loaded[key] = load_run(path)
    if not loaded:
        raise DataFormatError(f"{PAPER}: the paper alone cannot be compared; give a run folder "
                              f"beside it")
    first = next(iter(loaded.values()))
    names_taken = _names(list(loaded.values()))
    columns = []
    for name in wanted:
        if name == PAPER:
            columns.append(paper_column(first))
        else:
            run = loaded[str(Path(name).resolve())]
            columns.append(run_column(run, names_taken[str(run.path)]))
    return columns


def _names(runs: Sequence[LoadedRun]) -> dict[str, str]:
    """A short name per run: its folder's name, with its parent's where two share one."""
    names = [r.path.name for r in runs]
    out = {}
    for run, name in zip(runs, names, strict=True):
        out[str(run.path)] = (f"{run.path.parent.name}/{name}" if names.count(name) > 1
                              else name)
    return out


def compare_columns(columns: Sequence[Column]) -> Comparison:
    """The comparison of ``columns`` (ratios to the first)."""
    cells: dict[str, Cell] = {}
    for column in sorted(columns, key=lambda c: c.is_paper):  # the runs' cells first
        for cid, cell in column.cells.items():
            cells.setdefault(cid, cell)
    order = list(cells)
    shared = [c for c in order if all(c in col.values for col in columns)]
    runs = [col for col in columns if not col.is_paper]
    # apart: measured by some runs, not all (a figure only the paper prints is no measurement)
    apart = [c for c in order if c not in shared and any(c in col.values for col in runs)]
    base = columns[0]
    ratios: dict[str, list[Ratio]] = {}
    for cid in shared:
        ratios[cid] = [compare_values(cells[cid], base.values[cid], col.values[cid],
                                      paper=base.is_paper or col.is_paper)
                       for col in columns[1:]]
    return Comparison(columns=list(columns), cells=cells, shared=shared, apart=apart,
                      ratios=ratios)


def compare_runs(names: Sequence[str | Path], *, paper: bool = False) -> Comparison:
    """Read ``names`` (:func:`read_columns`) and compare them (:func:`compare_columns`); the
    machine kinds are left to the caller (``evsmap compare`` names them by the gate's
    :func:`evsmap.gate.baseline.machine_kind`, a layer above this one)."""
    return compare_columns(read_columns(names, paper=paper))


def relative_text(rel: float | None) -> str:
    """``+-1.2 %`` (``-`` without a precision)."""
    return "-" if rel is None or math.isnan(rel) else f"+-{100 * rel:.1f} %"
