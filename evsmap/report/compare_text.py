"""A comparison of runs (:class:`~evsmap.report.compare.Comparison`) as text: Markdown
(``compare.md``), a long CSV frame (``compare.csv``, one line per cell and column) and JSON.

A timed value reads ``23.30 +-0.31`` (its median and the half-width of its 95 % interval, in the
cell's unit); a ratio ``0.86x +-3.3 %`` (relative: the two half-widths added) followed by
``within precision`` or ``differs``; an exact cell's ratio by ``equal`` or ``differ``.
"""

from __future__ import annotations

import math
from typing import Any

import pandas as pd

from evsmap.report.cells import format_number, format_ratio, md_escape
from evsmap.report.compare import Column, Comparison, Ratio, Value, relative_text

COMPARE_COLUMNS = ("cell", "table", "row", "label", "header", "unit", "timed", "run", "value",
                   "rel_ci", "half_width", "ratio", "ratio_rel_ci", "verdict", "shared",
                   "timing_flag")
"""Columns of :func:`compare_frame`: one line per cell and run (``ratio``: this run / the first
run; ``rel_ci``, ``ratio_rel_ci``: relative half-widths; ``half_width`` in the cell's unit)."""

EXTRA_TITLE = "Mapping runs beyond the tables"


def value_text(value: Value, timed: bool) -> str:
    """``23.30 +-0.31`` for a timed value with a precision, else the value alone (a flagged
    timing ends in `` ~``; the paper's figure reads as printed)."""
    if value.decimals is not None:  # the paper's figure, as printed
        return f"{value.value:.{value.decimals}f}"
    text = format_number(value.value, None)
    if timed and value.rel is not None:
        decimals = len(text.split(".")[1]) if "." in text else 0
        text += f" +-{abs(value.value) * value.rel:.{decimals}f}"
    return text + (" ~" if value.flag else "")


def ratio_text(ratio: Ratio) -> str:
    """``0.86x +-3.3 %, differs``; ``1.00x, equal``."""
    if ratio.ratio is None:
        return f"-, {ratio.verdict}"
    text = format_ratio(ratio.ratio)
    if ratio.rel is not None:
        text += f" {relative_text(ratio.rel)}"
    return f"{text}, {ratio.verdict}"


def _table_titles() -> dict[str, str]:
    from evsmap.tables.schema import load_tables

    titles = {tid: f"Table {t.number} - {t.title}" for tid, t in load_tables().items()}
    titles["extra"] = EXTRA_TITLE
    return titles


def machines_markdown(comparison: Comparison) -> list[str]:
    """The columns' machines, commits and runs, one column each."""
    cols = comparison.columns
    letters = [_letter(i) for i in range(len(cols))]
    out = ["| | " + " | ".join(f"{a}: {md_escape(c.name)}" for a, c in zip(letters, cols,
                                                                         strict=True)) + " |",
           "|---|" + "---|" * len(cols)]
    rows: list[tuple[str, Any]] = [
        ("machine", lambda c: c.machine),
        ("machine kind", lambda c: c.kind or "-"),
        ("commit", lambda c: c.commit[:12] if c.commit != "-" else "-"),
        ("run", lambda c: "-" if c.is_paper else
         ("quick (`--quick`)" if c.quick else "full") + (f", {c.started}" if c.started else "")),
        ("speed cells timed with", lambda c: c.timing),
        ("folder", lambda c: f"`{c.path}`" if c.path else "-"),
        ("cells with a value", lambda c: str(len(c.values))),
    ]
    for name, get in rows:
        out.append(f"| {name} | " + " | ".join(md_escape(get(c)) for c in cols) + " |")
    return out + [""]


def _letter(i: int) -> str:
    return chr(ord("A") + i) if i < 26 else f"R{i + 1}"


def summary_lines(comparison: Comparison) -> list[str]:
    """How many shared cells agree: the timed ones within their precision, the exact ones
    equal, and the geometric mean of each run's timed ratios to the first."""
    cols = comparison.columns
    out = []
    for i in range(len(cols) - 1):
        timed = [comparison.ratios[c][i] for c in comparison.shared
                 if comparison.cells[c].timed]
        exact = [comparison.ratios[c][i] for c in comparison.shared
                 if not comparison.cells[c].timed]
        within = sum(r.verdict == "within precision" for r in timed)
        differs = sum(r.verdict == "differs" for r in timed)
        equal = sum(r.verdict == "equal" for r in exact)
        logs = [math.log(r.ratio) for r in timed if r.ratio and r.ratio > 0]
        mean = (f"; their geometric mean {format_ratio(math.exp(sum(logs) / len(logs)))} "
                f"(from {format_ratio(math.exp(min(logs)))} to "
                f"{format_ratio(math.exp(max(logs)))})" if logs else "")
        out.append(f"- {_letter(i + 1)} / A: {len(timed)} timed cells, {within} within "
                   f"precision, {differs} differ{mean}; {len(exact)} exact cells, {equal} "
                   f"equal, {len(exact) - equal} differ.")
    out.append(f"- {len(comparison.apart)} cell(s) measured in only some of the runs "
               f"(listed at the end).")
    return out + [""]


PRECISION_NOTE = (
    "A timed value (FPS, Hz) is its median +- the half-width of the median's 95 % interval "
    "(the timing policy's precision, `index.md`'s \"Timing precision\"); `~` marks a flagged "
    "timing. A ratio of two timed values carries the two relative half-widths added "
    "(docs/results.md, \"Reading a ratio's precision\"): `within precision` when 1 lies in it, "
    "else `differs`. Counts, sizes and scores are exact: `equal` or `differ`. The paper's "
    "figures are known to their printed digits (half a unit of the last one); a measured "
    "count equals the paper's when it rounds to the printed figure.")


def compare_markdown(comparison: Comparison) -> str:
    """``compare.md``: the machines, a summary, the shared cells per table, the cells apart."""
    cols = comparison.columns
    names = [_letter(i) for i in range(len(cols))]
    out = ["# evsmap compare", ""] + machines_markdown(comparison)
    out += [PRECISION_NOTE, ""] + summary_lines(comparison)
    titles = _table_titles()
    by_table: dict[str, list[str]] = {}
    for cid in comparison.shared:
        by_table.setdefault(comparison.cells[cid].table, []).append(cid)
    for table, cids in by_table.items():
        out += [f"## {titles.get(table, table)}", "",
                "| System | Column | " + " | ".join(names) + " | "
                + " | ".join(f"{n} / A" for n in names[1:]) + " |",
                "|---|---|" + "---:|" * len(cols) + "---|" * (len(cols) - 1)]
        for cid in cids:
            cell = comparison.cells[cid]
            values = [value_text(c.values[cid], cell.timed) for c in cols]
            ratios = [ratio_text(r) for r in comparison.ratios[cid]]
            out.append("| " + " | ".join(md_escape(x) for x in (cell.label, cell.header,
                                                                *values, *ratios)) + " |")
        out.append("")
    if comparison.apart:
        out += ["## Measured in only some of the runs", "",
                "| Table | System | Column | " + " | ".join(names) + " |",
                "|---|---|---|" + "---:|" * len(cols)]
        for cid in comparison.apart:
            cell = comparison.cells[cid]
            values = [value_text(c.values[cid], cell.timed) if cid in c.values else "-"
                      for c in cols]
            out.append("| " + " | ".join(md_escape(x) for x in (
                titles.get(cell.table, cell.table).split(" - ")[0], cell.label, cell.header,
                *values)) + " |")
        out.append("")
    return "\n".join(out).rstrip() + "\n"


def compare_frame(comparison: Comparison) -> pd.DataFrame:
    """``compare.csv``: one line per cell (shared, then apart) and run
    (:data:`COMPARE_COLUMNS`)."""
    lines = []
    for cid in [*comparison.shared, *comparison.apart]:
        cell = comparison.cells[cid]
        shared = cid in comparison.ratios
        for i, col in enumerate(comparison.columns):
            value = col.values.get(cid)
            ratio = comparison.ratios[cid][i - 1] if shared and i > 0 else None
            lines.append({
                "cell": cid, "table": cell.table, "row": cell.row, "label": cell.label,
                "header": cell.header, "unit": cell.unit, "timed": cell.timed, "run": col.name,
                "value": None if value is None else value.value,
                "rel_ci": None if value is None else value.rel,
                "half_width": (None if value is None or value.rel is None
                               else abs(value.value) * value.rel),
                "ratio": None if ratio is None else ratio.ratio,
                "ratio_rel_ci": None if ratio is None else ratio.rel,
                "verdict": None if ratio is None else ratio.verdict, "shared": shared,
                "timing_flag": None if value is None else value.flag})
    frame = pd.DataFrame(lines, columns=list(COMPARE_COLUMNS))
    for name in ("value", "rel_ci", "half_width", "ratio", "ratio_rel_ci"):
        frame[name] = pd.to_numeric(frame[name]).astype("float64")
    return frame


def _column_json(col: Column) -> dict[str, Any]:
    return {"name": col.name, "path": col.path, "machine": col.machine, "kind": col.kind,
            "commit": col.commit, "quick": col.quick, "started": col.started, "gpu": col.gpu,
            "timing": col.timing}


def _value_json(value: Value | None) -> dict[str, Any] | None:
    if value is None:
        return None
    return {"value": value.value, "rel_ci": value.rel, "timing_flag": value.flag}


def compare_json(comparison: Comparison) -> dict[str, Any]:
    """The comparison as one JSON object: ``columns`` (machines and commits), ``shared`` (each
    cell with every run's value and each run's ratio to the first) and ``apart``."""
    def cell_json(cid: str) -> dict[str, Any]:
        cell = comparison.cells[cid]
        out: dict[str, Any] = {
            "cell": cid, "table": cell.table, "row": cell.row, "column": cell.column,
            "label": cell.label, "header": cell.header, "unit": cell.unit, "timed": cell.timed,
            "values": {c.name: _value_json(c.values.get(cid)) for c in comparison.columns}}
        if cid in comparison.ratios:
            out["ratios"] = {c.name: {"ratio": r.ratio, "rel_ci": r.rel, "verdict": r.verdict}
                             for c, r in zip(comparison.columns[1:], comparison.ratios[cid],
                                             strict=True)}
        return out

    return {"columns": [_column_json(c) for c in comparison.columns],
            "ratio_of": f"each run / {comparison.columns[0].name}",
            "shared": [cell_json(c) for c in comparison.shared],
            "apart": [cell_json(c) for c in comparison.apart]}
