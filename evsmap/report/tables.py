"""The paper's tables with the measured values beside the printed ones.

:func:`table_frame` joins a :class:`~evsmap.tables.PaperTable` with the run's
:class:`~evsmap.runner.records.CellRecord` s into a long frame (one line per row and measured
column); :func:`table_markdown` prints the table as the paper lays it out, every cell
``measured / paper (ratio)``, with numbered footnotes. :func:`extra_frame` and
:func:`extra_markdown` (:mod:`evsmap.report.extra`, named here too) do the same for the
measurements beyond the paper (``extra/...`` records); :mod:`evsmap.report.cells` formats the
numbers.

Every number shown as measured comes from a record's ``values``; nothing is derived or filled in.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

import pandas as pd

from evsmap.report.cells import (
    Footnotes,
    format_number,
    format_ratio,
    header_with_unit,
    md_escape,
    number,
    record_calibration,
    record_note,
    row_label,
)
from evsmap.report.extra import (
    EXTRA_COLUMNS,
    EXTRA_COUNTS,
    EXTRA_VALUES,
    PROXY_SECTION,
    SIZE_CLAIM,
    extra_frame,
    extra_markdown,
    extra_records,
    labels_lines,
    proxy_accuracy_markdown,
    proxy_mapping_markdown,
    size_claim_lines,
)
from evsmap.runner.records import CellRecord
from evsmap.tables.schema import CellSpec, Column, PaperTable, expand

FRAME_COLUMNS = ("table", "row", "label", "column", "header", "unit", "measured", "paper",
                 "paper_printed", "paper_best", "ratio", "status", "note", "timing_flag",
                 "calibration_gmacs", "rel_ci", "bound", "busy_share")
"""Columns of :func:`table_frame` (``bound``, ``busy_share``: where a timed pass's time went,
:mod:`evsmap.measure.pass_timing`; ``host`` on the CPU, ``launch`` or ``device`` on a GPU)."""

STATUSES = ("ok", "n/a", "error", "not run", "no value", "paper only")
"""Cell statuses in a frame: measured; cannot be measured here (``note`` says what is
missing); the run failed; no record; a record without a value for the column; a row evsmap does
not implement."""


# ------------------------------------------------------------------------------- cells
def _cell_index(table: PaperTable, records: Mapping[str, CellRecord],
                specs: Iterable[CellSpec] | None) -> dict[tuple[str, str], CellRecord | None]:
    """(row, column) -> the record that fills it (``None``: expected but not run)."""
    specs = expand(table) if specs is None else [s for s in specs if s.table == table.id]
    out: dict[tuple[str, str], CellRecord | None] = {}
    for spec in specs:
        rec = records.get(spec.key)
        for cid in spec.metrics:
            out[(spec.row, cid)] = rec
    # Records whose key no spec knows (written with other options) still fill their cells.
    for rec in records.values():
        if rec.table != table.id or rec.key.startswith("extra/"):
            continue
        for cid in rec.metrics:
            if out.get((rec.row, cid)) is None and (rec.row, cid) in table.cells:
                out[(rec.row, cid)] = rec
    return out



# ------------------------------------------------------------------------------- frames
def table_frame(table: PaperTable, records: Mapping[str, CellRecord],
                specs: Iterable[CellSpec] | None = None,
                skipped: Mapping[str, str] | None = None) -> pd.DataFrame:
    """One line per row (paper order) and non-flag column (paper order) of ``table``.

    Args:
        records: the run's records by key.
        specs: the cell specs the records were run from (``expand`` of the tables; specs of
            other tables are ignored). ``None``: :func:`~evsmap.tables.expand` of ``table``.
        skipped: cell key -> why the run left it out on purpose (``--quick``); such a cell
            without a record is ``not run`` with that reason as its note.

    ``measured`` and ``paper`` are in the column's printed unit (base value / ``Column.scale``),
    ``ratio = measured / paper`` where both exist; ``status`` is one of :data:`STATUSES`;
    ``note`` explains n/a (the record's reason), error ("error: ...") and unrun cells, and
    carries the record's notes for measured ones.
    """
    specs = None if specs is None else list(specs)
    index = _cell_index(table, records, specs)
    skipped = skipped or {}
    why_skipped = {(s.row, cid): skipped[s.key]
                   for s in (expand(table) if specs is None else specs)
                   if s.table == table.id and s.key in skipped for cid in s.metrics}
    lines = []
    for system in table.rows:
        for col in table.columns:
            if col.kind == "flag":
                continue
            cell = table.cell(system.id, col.id)
            paper = None if cell.number is None else float(cell.number)
            measured = None
            flag = calibration = precision = bound = busy_share = None
            if not system.implemented:
                status, note = "paper only", ""
            elif (system.id, col.id) not in index or index[(system.id, col.id)] is None:
                status = "not run"
                note = why_skipped.get((system.id, col.id), "not run")
            else:
                rec = index[(system.id, col.id)]
                assert rec is not None
                note = record_note(rec)
                if rec.status == "na":
                    status = "n/a"
                elif rec.status == "error":
                    status = "error"
                else:
                    value = number(rec.values.get(col.id))
                    if value is None:
                        status = "no value"
                        note = "; ".join(x for x in (
                            f"the record holds no value for {col.id!r}", note) if x)
                    else:
                        status, measured = "ok", value / col.scale
                        flag = (rec.details or {}).get("timing_flag")
                        if col.timing:
                            calibration = record_calibration(rec)
                            precision = number((rec.details or {}).get("rel_ci"))
                            busy = (rec.details or {}).get("busy") or {}
                            bound, busy_share = busy.get("bound"), busy.get("busy_share")
            ratio = (measured / paper if measured is not None and paper is not None
                     and paper != 0.0 else None)
            lines.append({"table": table.id, "row": system.id, "label": system.label,
                          "column": col.id, "header": col.header, "unit": col.unit,
                          "measured": measured, "paper": paper,
                          "paper_printed": cell.printed, "paper_best": bool(cell.bold),
                          "ratio": ratio,
                          "status": status, "note": note, "timing_flag": flag,
                          "calibration_gmacs": calibration, "rel_ci": precision,
                          "bound": bound, "busy_share": number(busy_share)})
    frame = pd.DataFrame(lines, columns=list(FRAME_COLUMNS))
    for name in ("measured", "paper", "ratio", "calibration_gmacs", "rel_ci", "busy_share"):
        frame[name] = pd.to_numeric(frame[name]).astype("float64")
    return frame



# ------------------------------------------------------------------------------- markdown
def _paper_text(cell) -> str:
    text = cell.printed if cell.number is not None else "-"
    return f"**{text}**" if cell.bold and cell.number is not None else text


def _cell_markdown(line: Mapping[str, Any], cell, notes: Footnotes,
                   timing: bool = False) -> str:
    """One cell. ``timing``: a speed or rate column, whose ``measured ÷ paper`` would divide
    this CPU by the paper's GPU or Jetson, so no ratio is printed (the table's relative view
    compares systems instead)."""
    paper = _paper_text(cell)
    status = line["status"]
    if status == "paper only":
        return f"- / {paper}"
    ref = notes.ref(line["note"]) if line["note"] and line["note"] != "not run" else ""
    if status == "ok":
        measured = format_number(line["measured"], cell.decimals if cell.number is not None
                                 else None)
        flagged = isinstance(line.get("timing_flag"), str) and line["timing_flag"]
        text = f"{measured}{TIMING_MARK if flagged else ''} / {paper}"
        if not pd.isna(line["ratio"]) and not timing:
            text += f" ({format_ratio(line['ratio'])})"
    elif status == "n/a":
        text = f"n/a / {paper}"
    elif status == "error":
        text = f"error / {paper}"
    elif status == "not run":
        text = f"not run / {paper}"
    else:
        text = f"- / {paper}"
    return f"{text} {ref}".strip()


BOUND_HEADER = "GPU pass"
BOUND_NOTE = ("GPU pass: the share of a timed pass the GPU spent running its kernels (torch's "
              "profiler) and what bounds it: *launch-bound* below 50 % (the GPU waits on the "
              "host's kernel launches: the figure measures Python and the launch path, and "
              "moves with the host), else *device-bound*.")


def _gpu_bounds(frame: pd.DataFrame) -> dict[str, str]:
    """Per row, where its GPU speed cells' passes went ("23 % busy, launch-bound"); empty
    when no timed cell ran on a GPU (a CPU run's tables keep their columns)."""
    out: dict[str, str] = {}
    for line in frame.to_dict("records"):
        bound = line.get("bound")
        if bound not in ("launch", "device"):
            continue
        share = line.get("busy_share")
        busy = "" if share is None or pd.isna(share) else f"{100 * share:.0f} % busy, "
        out.setdefault(line["row"], f"{busy}{bound}-bound")
    return out


TIMING_MARK = " ~"
"""Appended to a measured value whose timing is flagged (unstable or taken on a busy machine);
the cell's note says which."""


def _column_details(col: Column) -> str:
    parts = []
    if col.datasets:
        parts.append(", ".join(col.datasets) + (f" ({col.split})" if col.split else ""))
    if col.input_size is not None:
        h, w = col.input_size
        parts.append(f"input {w}x{h}" + (" (assumed)" if col.input_size_source == "assumed"
                                         else ""))
    if col.resolution is not None:
        parts.append(f"voxel {col.resolution:g} m" + (" (assumed)"
                                                      if col.resolution_source == "assumed"
                                                      else ""))
    if col.note:
        parts.append(col.note)
    return "; ".join(parts)


def _measured_on(table: PaperTable, column: Column, records: Mapping[str, CellRecord]) -> str:
    """`` on SEQ`` for a rate column whose measured cells all come from one sequence (Table
    IV's Runtime: one sequence for every system), else nothing."""
    if column.quantity != "runtime_hz":
        return ""
    seqs = {str(r.inputs.get("sequence")) for r in records.values()
            if r.table == table.id and r.status == "ok" and column.id in r.values
            and r.inputs.get("sequence")}
    return f", measured on {seqs.pop()}" if len(seqs) == 1 else ""


def table_markdown(table: PaperTable, records: Mapping[str, CellRecord],
                   specs: Iterable[CellSpec] | None = None, *,
                   extras: Iterable[CellRecord] | None = None,
                   frame: pd.DataFrame | None = None) -> str:
    """The table as the paper prints it, every measured cell ``measured / paper (ratio)``.

    Flag columns (Table III's check marks) print as in the paper. Cells that were not measured
    read ``n/a`` / ``error`` / ``not run`` with a footnote saying why; rows evsmap does not
    implement read ``- / paper``. ``extras``: the ``extra`` records, printed after the table
    under "Measured beyond the paper" (Table IV).
    """
    frame = table_frame(table, records, specs) if frame is None else frame
    by_cell = {(r["row"], r["column"]): r for r in frame.to_dict("records")}
    notes = Footnotes()
    out = [f"# Table {table.number} - {table.title}", ""]
    if table.caption:
        out += [f"*{table.caption}*", ""]
    if table.note:
        out += [f"Note: {' '.join(table.note.split())}", ""]
    out += ["Each cell: measured / paper (measured ÷ paper; not for speeds and rates, where it "
            "would compare this machine with the paper's: see the relative view below). "
            "Measured values are evsmap's on this machine; bold marks the paper's best values; "
            "`paper only`: evsmap does not implement the row; `~` after a measured speed: its "
            "timing is flagged (it never reached a steady median, or the machine was busy; the "
            "note says which). Bracketed numbers refer to the notes below the table.", ""]
    headers = ["System"] + [md_escape(header_with_unit(c) + _measured_on(table, c, records))
                            for c in table.columns]
    gpu_rows = _gpu_bounds(frame)
    if gpu_rows:
        headers.append(BOUND_HEADER)
    out.append("| " + " | ".join(headers) + " |")
    out.append("|" + "|".join(["---"] + [":---:" if c.kind == "flag" else "---:"
                                         for c in table.columns]
                              + ([":---"] if gpu_rows else [])) + "|")
    for system in table.rows:
        label = md_escape(row_label(system))
        if not system.implemented:
            label += " (paper only)"
        if system.note:
            label += f" {notes.ref(system.note)}"
        cells = [label]
        for col in table.columns:
            cell = table.cell(system.id, col.id)
            if col.kind == "flag":
                cells.append(cell.printed)
                continue
            line = by_cell.get((system.id, col.id))
            cells.append(md_escape(_cell_markdown(line, cell, notes, col.timing))
                         if line is not None else _paper_text(cell))
        if gpu_rows:
            cells.append(gpu_rows.get(system.id, ""))
        out.append("| " + " | ".join(cells) + " |")
    out.append("")
    if gpu_rows:
        out += [BOUND_NOTE, ""]
    if table.footnotes:
        out += ["Marks as printed in the paper:", ""]
        out += [f"- {m} {md_escape(t)}" for m, t in table.footnotes.items()] + [""]
    details = [(c, _column_details(c)) for c in table.columns if c.kind != "flag"]
    details = [(c, d) for c, d in details if d]
    if details:
        out += ["Columns:", ""]
        out += [f"- {md_escape(header_with_unit(c))}: {d}" for c, d in details]
        out.append("")
    if notes.texts:
        out += ["Notes:", ""] + notes.markdown() + [""]
    counts = frame["status"].value_counts()
    out += ["Cells: " + ", ".join(f"{int(counts.get(s, 0))} {s}" for s in STATUSES
                                  if counts.get(s, 0)), ""]
    if extras is not None:
        out += extra_markdown(extras)
    return "\n".join(out).rstrip() + "\n"


__all__ = ["BOUND_HEADER", "BOUND_NOTE", "EXTRA_COLUMNS", "EXTRA_COUNTS", "EXTRA_VALUES",
           "FRAME_COLUMNS", "PROXY_SECTION", "SIZE_CLAIM", "STATUSES", "TIMING_MARK", "Footnotes",
           "extra_frame", "extra_markdown", "extra_records", "format_number", "format_ratio",
           "header_with_unit", "labels_lines", "proxy_accuracy_markdown",
           "proxy_mapping_markdown", "record_calibration", "record_note", "size_claim_lines",
           "table_frame", "table_markdown"]
