"""The paper's tables with the measured values beside the printed ones.

:func:`table_frame` joins a :class:`~evsmap.tables.PaperTable` with the run's
:class:`~evsmap.runner.records.CellRecord` s into a long frame (one line per row and measured
column); :func:`table_markdown` prints the table as the paper lays it out, every cell
``measured / paper (ratio)``, with numbered footnotes. :func:`extra_frame` and
:func:`extra_markdown` do the same for the measurements beyond the paper (``extra/...`` records).

Every number shown as measured comes from a record's ``values``; nothing is derived or filled in.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from typing import Any

import pandas as pd

from evsmap.runner.records import CellRecord, needs_text
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

EXTRA_VALUES = ("update_hz", "segment_update_hz", "map_bytes", "map_bytes_full",
                "map_bytes_colour", "map_bytes_message", "octomap_memory_bytes", "map_nbytes",
                "rss_added_bytes",
                "peak_rss_bytes", "nodes", "leaves", "pruned_share", "precision", "recall",
                "semantic_accuracy", "semantic_accuracy_all", "map_miou", "frames", "miou")
"""Value keys of the ``extra`` records (docs/measurement.md, "Quantities";
``miou``: the synthrooms proxy networks')."""

PROXY_SECTION = "Synthetic proxy (evsmap's synthrooms, not the paper's datasets)"
"""Title of the ``reproduce --train`` sections (``extra/proxy...`` records)."""

EXTRA_COUNTS = frozenset({"map_bytes", "map_bytes_full", "map_bytes_colour", "map_bytes_message",
                          "octomap_memory_bytes", "map_nbytes",
                          "rss_added_bytes", "peak_rss_bytes", "nodes", "leaves", "frames"})
"""Value keys that are counts (bytes, nodes, frames): integers in :func:`extra_frame`."""

EXTRA_COLUMNS = ("key", "row", "label", "sequence", "voxel_size", "status", *EXTRA_VALUES,
                 "labels_from", "note")
"""Columns of :func:`extra_frame` (values in base units: Hz, bytes, fractions; ``labels_from``:
the labels a semantic map was made with, :func:`evsmap.report.detail.labels_text`)."""

# (value key, header, divisor to printed unit, decimals)
_EXTRA_PRINT = (
    ("update_hz", "Update (Hz)", 1.0, 1),
    ("segment_update_hz", "Segmentation + update (Hz)", 1.0, 1),
    ("map_bytes", "Map size (MB)", 1e6, 2),
    ("map_bytes_full", "Full state (MB)", 1e6, 2),
    ("octomap_memory_bytes", "OctoMap memoryUsage() formula (MB)", 1e6, 2),
    ("map_nbytes", "Map arrays, measured (MB)", 1e6, 2),
    ("rss_added_bytes", "Peak RSS added by mapping, measured (MB)", 1e6, 1),
    ("nodes", "Nodes", 1.0, 0),
    ("leaves", "Leaves", 1.0, 0),
    ("pruned_share", "Pruned (%)", 0.01, 1),
    ("precision", "Occupancy precision (%)", 0.01, 1),
    ("recall", "Occupancy recall (%)", 0.01, 1),
    ("semantic_accuracy", "Semantic accuracy (%)", 0.01, 1),
    ("semantic_accuracy_all", "Semantic accuracy, no class = wrong (%)", 0.01, 1),
    ("map_miou", "Map mIoU (%)", 0.01, 1),
)


# ------------------------------------------------------------------------------- helpers
def _number(value: Any) -> float | None:
    """``value`` as a finite float, else ``None`` (bools are not numbers here)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    value = float(value)
    return value if math.isfinite(value) else None


def format_number(value: float, decimals: int | None) -> str:
    """``value`` with ``decimals`` digits after the point (2 when unknown), widened until it
    shows at least three significant digits (a measurement is shown one digit finer than the
    paper prints): ``format_number(4.278, 1) == "4.28"``, ``format_number(0.0123, 1) ==
    "0.0123"``, ``format_number(5, 0) == "5.00"``, ``format_number(143.2, 0) == "143"``."""
    d = 2 if decimals is None else max(0, decimals)
    if value != 0 and math.isfinite(value):
        d = max(d, 2 - math.floor(math.log10(abs(value))))
    return f"{value:.{d}f}"


def format_ratio(ratio: float) -> str:
    """``0.95x``; two significant digits (trailing zeros kept: ``0.040x``) below 0.1."""
    if ratio != 0 and abs(ratio) < 0.1:
        return f"{ratio:#.2g}x"
    return f"{ratio:.2f}x"


def header_with_unit(col: Column) -> str:
    """The printed header, with the unit added when the header does not show it (neither as
    the whole header, nor in brackets, nor as its last word: "1024x512 (val) FPS")."""
    if (not col.unit or col.header == col.unit or f"({col.unit})" in col.header
            or col.header.split()[-1] == col.unit):
        return col.header
    return f"{col.header} ({col.unit})"


def _row_label(system) -> str:
    return f"{system.label} ({system.year})" if system.year else system.label


def _md_escape(text: str) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ")


def _sequence_note(record: CellRecord) -> str | None:
    seq = record.inputs.get("sequence") if isinstance(record.inputs, dict) else None
    if not seq:
        return None
    if any(str(seq) in n for n in record.notes):
        return None
    return f"measured on sequence '{seq}'"


def record_note(record: CellRecord, *, sequence: bool = True) -> str:
    """What a cell's note says about its record: the reason of an ``na`` record, the error of a
    failed one, the notes of an ``ok`` one (with the sequence it was measured on, from
    ``inputs["sequence"]``, unless ``sequence`` is false or the notes name it)."""
    if record.status == "na":
        return record.reason or needs_text(record.needs)
    if record.status == "error":
        return f"error: {record.error or 'unknown error'}"
    notes = [str(n) for n in record.notes if str(n).strip()]
    seq = _sequence_note(record) if sequence else None
    if seq:
        notes.append(seq)
    return "; ".join(notes)


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


def record_calibration(rec: CellRecord) -> float | None:
    """The calibration (G MAC/s) a timing record was taken under: ``calibration_gmacs``, else
    (records written before it existed) the geometric mean of its two contention probes."""
    details = rec.details or {}
    value = _number(details.get("calibration_gmacs"))
    if value is not None:
        return value
    machine = details.get("contention") or {}
    try:
        a = float(machine["before"]["calibration_gmacs"])
        b = float(machine["after"]["calibration_gmacs"])
    except (KeyError, TypeError, ValueError):
        return None
    return math.sqrt(a * b) if a > 0 and b > 0 else None


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
                    value = _number(rec.values.get(col.id))
                    if value is None:
                        status = "no value"
                        note = "; ".join(x for x in (
                            f"the record holds no value for {col.id!r}", note) if x)
                    else:
                        status, measured = "ok", value / col.scale
                        flag = (rec.details or {}).get("timing_flag")
                        if col.timing:
                            calibration = record_calibration(rec)
                            precision = _number((rec.details or {}).get("rel_ci"))
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
                          "bound": bound, "busy_share": _number(busy_share)})
    frame = pd.DataFrame(lines, columns=list(FRAME_COLUMNS))
    for name in ("measured", "paper", "ratio", "calibration_gmacs", "rel_ci", "busy_share"):
        frame[name] = pd.to_numeric(frame[name]).astype("float64")
    return frame


def extra_records(records: Iterable[CellRecord]) -> list[CellRecord]:
    """The ``extra/...`` records, ordered by sequence, voxel size, Table IV row order, key."""
    order = {r: i for i, r in enumerate(("orgbmap", "tesamap", "tfeagmap", "mesamap", "evsmap",
                                          "octomap-cpp"))}
    extras = [r for r in records if r.table == "extra" or r.key.startswith("extra/")]
    return sorted(extras, key=lambda r: (str(r.inputs.get("sequence", "")),
                                         _number(r.inputs.get("voxel_size")) or 0.0,
                                         order.get(r.row, len(order)), r.key))


def extra_frame(records: Iterable[CellRecord]) -> pd.DataFrame:
    """The ``extra`` records, one line each, values in base units (:data:`EXTRA_COLUMNS`)."""
    lines = []
    for rec in extra_records(records):
        line: dict[str, Any] = {
            "key": rec.key, "row": rec.row, "label": rec.label,
            "sequence": str(rec.inputs.get("sequence", "")),
            "voxel_size": _number(rec.inputs.get("voxel_size")),
            "status": {"na": "n/a"}.get(rec.status, rec.status),
            "labels_from": _labels_column(rec),
            "note": record_note(rec, sequence=False)}
        for key in EXTRA_VALUES:
            line[key] = _number(rec.values.get(key)) if rec.status == "ok" else None
        lines.append(line)
    frame = pd.DataFrame(lines, columns=list(EXTRA_COLUMNS))
    for name in ("voxel_size", *EXTRA_VALUES):
        # counts stay integers in the CSV (nullable: a cell without a value stays empty)
        kind = "Int64" if name in EXTRA_COUNTS else "float64"
        frame[name] = pd.to_numeric(frame[name]).astype(kind)
    return frame


def _labels_column(rec: CellRecord) -> str | None:
    """The labels a semantic map record was made with, in words; None for the others."""
    from evsmap.report.detail import labels_of, labels_text

    labels = labels_of(rec) if rec.inputs.get("segmenter") else None
    return None if labels is None else labels_text(labels)


_SEMANTIC_VALUES = ("semantic_accuracy", "semantic_accuracy_all", "map_miou")
"""The extra table's semantic columns."""


def labels_lines(recs: Iterable[CellRecord]) -> list[str]:
    """Which labels the semantic columns of one extra table used: each source with its rows
    (none where no row has a semantic figure)."""
    sources: dict[str, list[str]] = {}
    for rec in recs:
        text = _labels_column(rec) if rec.status == "ok" else None
        if text is not None and any(_number(rec.values.get(k)) is not None
                                    for k in _SEMANTIC_VALUES):
            sources.setdefault(text, []).append(rec.label or rec.row)
    if not sources:
        return []
    parts = [f"{_md_escape(text)} ({', '.join(_md_escape(r) for r in rows)})"
             for text, rows in sources.items()]
    return ["Labels of the semantic columns: " + "; ".join(parts) + ".", ""]


# ------------------------------------------------------------------------------- markdown
class Footnotes:
    """Numbered footnotes; the same text gets the same number."""

    def __init__(self) -> None:
        self.texts: list[str] = []

    def ref(self, text: str) -> str:
        text = " ".join(str(text).split())
        if not text:
            return ""
        if text not in self.texts:
            self.texts.append(text)
        return f"[{self.texts.index(text) + 1}]"

    def markdown(self) -> list[str]:
        return [f"{i}. {_md_escape(t)}" for i, t in enumerate(self.texts, 1)]


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
    if col.voxel_size is not None:
        parts.append(f"voxel {col.voxel_size:g} m" + (" (assumed)"
                                                     if col.voxel_size_source == "assumed"
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
    headers = ["System"] + [_md_escape(header_with_unit(c) + _measured_on(table, c, records))
                            for c in table.columns]
    gpu_rows = _gpu_bounds(frame)
    if gpu_rows:
        headers.append(BOUND_HEADER)
    out.append("| " + " | ".join(headers) + " |")
    out.append("|" + "|".join(["---"] + [":---:" if c.kind == "flag" else "---:"
                                         for c in table.columns]
                              + ([":---"] if gpu_rows else [])) + "|")
    for system in table.rows:
        label = _md_escape(_row_label(system))
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
            cells.append(_md_escape(_cell_markdown(line, cell, notes, col.timing))
                         if line is not None else _paper_text(cell))
        if gpu_rows:
            cells.append(gpu_rows.get(system.id, ""))
        out.append("| " + " | ".join(cells) + " |")
    out.append("")
    if gpu_rows:
        out += [BOUND_NOTE, ""]
    if table.footnotes:
        out += ["Marks as printed in the paper:", ""]
        out += [f"- {m} {_md_escape(t)}" for m, t in table.footnotes.items()] + [""]
    details = [(c, _column_details(c)) for c in table.columns if c.kind != "flag"]
    details = [(c, d) for c, d in details if d]
    if details:
        out += ["Columns:", ""]
        out += [f"- {_md_escape(header_with_unit(c))}: {d}" for c, d in details]
        out.append("")
    if notes.texts:
        out += ["Notes:", ""] + notes.markdown() + [""]
    counts = frame["status"].value_counts()
    out += ["Cells: " + ", ".join(f"{int(counts.get(s, 0))} {s}" for s in STATUSES
                                  if counts.get(s, 0)), ""]
    if extras is not None:
        out += extra_markdown(extras)
    return "\n".join(out).rstrip() + "\n"


def extra_markdown(records: Iterable[CellRecord]) -> list[str]:
    """The "Measured beyond the paper" section: one table per sequence (and voxel size)."""
    extras = [r for r in extra_records(records) if not _is_proxy(r)]
    proxy = [r for r in extra_records(records) if r.key.startswith("extra/proxy-mapping/")]
    out = ["## Measured beyond the paper", ""]
    if not extras and not proxy:
        return out + ["No measurements beyond the paper in this run.", ""]
    if not extras:
        return out + proxy_mapping_markdown(proxy)
    out += ["Every mapping system on the sequences this run had, with the map update rate alone "
            "and with segmentation (segmentation + update), the size of the map file each system "
            "itself writes (Table IV's \"Map Size\"; classic-semantic: semantic_slam's "
            "ColorOcTree) and of evsmap's full resumable state, the memory the map would take "
            "by OctoMap's memoryUsage() formula in the original C++ node types (OctoMap 16 B "
            "a node, semantic_slam 48 B a Bayesian and 32 B a max node, EVSMap 32 B, plus 64 B "
            "per inner node's child array; a model, not a measurement), the bytes of the "
            "arrays evsmap holds it in and the peak resident memory mapping added to the "
            "process (both measured), its nodes, leaves and the share of the finest leaves "
            "pruned, and the map's quality against "
            "the ground truth (occupancy precision and recall, semantic accuracy and mIoU of "
            "the occupied voxels), so a smaller map is never bought unseen with a worse one.",
            ""]
    groups: dict[tuple[str, float | None], list[CellRecord]] = {}
    for rec in extras:
        key = (str(rec.inputs.get("sequence", "") or "unknown"),
               _number(rec.inputs.get("voxel_size")))
        groups.setdefault(key, []).append(rec)
    for (seq, voxel), recs in groups.items():
        title = f"### Sequence `{seq}`"
        if voxel is not None:
            title += f", voxel size {voxel:g} m"
        out += [title, ""]
        notes = Footnotes()
        frames = {n for n in (_number(r.values.get("frames")) for r in recs if r.status == "ok")
                  if n is not None}
        if len(frames) == 1:
            out += [f"{int(frames.pop())} frames.", ""]
        headers = ["System"] + [h for _, h, _, _ in _EXTRA_PRINT]
        out.append("| " + " | ".join(headers) + " |")
        out.append("|---|" + "|".join("---:" for _ in _EXTRA_PRINT) + "|")
        for rec in recs:
            note = record_note(rec, sequence=False)
            label = _md_escape(rec.label or rec.row)
            if note:
                label += f" {notes.ref(note)}"
            cells = [label]
            for value_key, _, div, dec in _EXTRA_PRINT:
                value = _number(rec.values.get(value_key)) if rec.status == "ok" else None
                if rec.status == "na":
                    cells.append("n/a")
                elif rec.status == "error":
                    cells.append("error")
                elif value is None:
                    cells.append("-")
                else:
                    cells.append(format_number(value / div, dec))
            out.append("| " + " | ".join(cells) + " |")
        out.append("")
        out += labels_lines(recs)
        out += size_claim_lines(recs)
        if notes.texts:
            out += notes.markdown() + [""]
    return out + (proxy_mapping_markdown(proxy) if proxy else [])


SIZE_CLAIM = ("tfeagmap", "evsmap", 2.6)
"""Table IV's map-size claim as this report checks it: (compared row, EVSMap's row, the paper's
"up to" factor by which EVSMap's map is smaller)."""


def size_claim_lines(recs: Iterable[CellRecord]) -> list[str]:
    """One paragraph on the paper's map-size claim for one sequence: the ratio of the two
    saved files and what makes it (bytes a node, nodes), when both rows were measured."""
    by_row = {r.row: r for r in recs if r.status == "ok"}
    other, ours, factor = SIZE_CLAIM
    if other not in by_row or ours not in by_row:
        return []
    a, b = by_row[other].values, by_row[ours].values
    size_a, size_b = _number(a.get("map_bytes")), _number(b.get("map_bytes"))
    nodes_a, nodes_b = _number(a.get("nodes")), _number(b.get("nodes"))
    if not (size_a and size_b and nodes_a and nodes_b):
        return []
    ratio = size_a / size_b
    verdict = ("reproduces" if ratio >= factor else
               "does not reproduce" + (" (EVSMap's map is smaller, by less)" if ratio > 1 else
                                       ": EVSMap's map is the larger one"))
    label_a, label_b = by_row[other].label or other, by_row[ours].label or ours
    return [f"Map size, {label_a} / {label_b} (each the file the system itself saves): "
            f"{ratio:.2f}x. The paper reports EVSMap's map up to {factor:g}x smaller; here "
            f"that {verdict}. Bytes a node in the file: {size_a / nodes_a:.1f} against "
            f"{size_b / nodes_b:.1f}; nodes: {int(nodes_a):,} against {int(nodes_b):,} "
            f"({nodes_b / nodes_a:.2f}x).", ""]


def _is_proxy(record: CellRecord) -> bool:
    return record.key.startswith(("extra/proxy/", "extra/proxy-mapping/"))


def _pct_text(value: Any) -> str:
    number = _number(value)
    return "-" if number is None else format_number(100 * number, 1)


def _status_text(rec: CellRecord) -> str | None:
    return {"na": "n/a", "error": "error"}.get(rec.status)


def proxy_accuracy_markdown(records: Iterable[CellRecord]) -> list[str]:
    """The "Synthetic proxy" section of Tables I and III: each network trained by
    ``reproduce --train`` on synthrooms (``extra/proxy/...`` records), never the paper's
    columns."""
    recs = [r for r in extra_records(records) if r.key.startswith("extra/proxy/")]
    if not recs:
        return []
    out = [f"## {PROXY_SECTION}", "",
           "Networks trained by `evsmap reproduce --train` on evsmap's synthetic rooms "
           "(`synthrooms`, NYUv2's 40 classes), NOT on the paper's datasets: these values are "
           "no measurement of the paper's columns above. Test mIoU: measured on the synthrooms "
           "test split as the accuracy cells measure; val mIoU, epochs and recipe: from the "
           "weights card.", "",
           "| Network | Test mIoU (%) | Val mIoU (%) | Epochs | Recipe | Weights card |",
           "|---|---:|---:|---:|---|---|"]
    for rec in recs:
        d = rec.details
        status = _status_text(rec)
        test = status or _pct_text(rec.values.get("miou"))
        card = (rec.notes[-1] if rec.status == "ok" and rec.notes else
                rec.reason or rec.error or "")
        out.append("| " + " | ".join(_md_escape(str(x)) for x in (
            rec.row, test, _pct_text(d.get("val_miou")), d.get("epochs") or "-",
            d.get("recipe") or "-", card)) + " |")
    return out + [""]


_PROXY_SCORES = ("semantic_accuracy", "map_miou", "precision", "recall")


def proxy_mapping_markdown(records: Iterable[CellRecord]) -> list[str]:
    """Table IV's part of the "Synthetic proxy" section: TFEAGMap's and EVSMap's maps of one
    synthrooms test room with a trained network's labels, scored against the room's ground
    truth."""
    recs = list(records)
    out = [f"### {PROXY_SECTION}", "",
           "TFEAGMap's (classic-semantic) and EVSMap's (multiclass-bayes) updaters on one "
           "synthrooms test room with the labels of a network trained by `evsmap reproduce "
           "--train` (real network errors, not the oracle's), each map's occupied voxels scored "
           "against the room's ground truth.", ""]
    notes = Footnotes()
    headers = {k: h for k, h, _, _ in _EXTRA_PRINT}  # the extra tables' words for each value
    out += ["| System | Sequence | Frames | " + " | ".join(headers[k] for k in (
        *_PROXY_SCORES, "update_hz")) + " |", "|---|---|---:|---:|---:|---:|---:|---:|"]
    for rec in recs:
        label = _md_escape(rec.label or rec.row)
        note = record_note(rec, sequence=False)
        if note:
            label += f" {notes.ref(note)}"
        status = _status_text(rec)
        v = rec.values
        frames = _number(v.get("frames"))
        hz = _number(v.get("update_hz"))
        cells = [status or (str(int(frames)) if frames is not None else "-")] + [
            status or _pct_text(v.get(k))
            for k in _PROXY_SCORES] + [
            status or ("-" if hz is None else format_number(hz, 1))]
        out.append("| " + " | ".join([label, _md_escape(str(rec.inputs.get("sequence", ""))),
                                      *cells]) + " |")
    out.append("")
    if notes.texts:
        out += notes.markdown() + [""]
    return out
