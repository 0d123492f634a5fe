"""What every table of the report prints a cell with: numbers, ratios, headers, notes.

Shared by the paper's tables (:mod:`evsmap.report.tables`), the measurements beyond them
(:mod:`evsmap.report.extra`), the comparison of runs (:mod:`evsmap.report.compare`) and the
LaTeX tables (:mod:`evsmap.report.latex`).
"""

from __future__ import annotations

import math
from typing import Any

from evsmap.runner.records import CellRecord, needs_text
from evsmap.tables.schema import Column


def number(value: Any) -> float | None:
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


def row_label(system) -> str:
    return f"{system.label} ({system.year})" if system.year else system.label


def md_escape(text: str) -> str:
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


def record_calibration(rec: CellRecord) -> float | None:
    """The calibration (G MAC/s) a timing record was taken under: ``calibration_gmacs``, else
    (records written before it existed) the geometric mean of its two contention probes."""
    details = rec.details or {}
    value = number(details.get("calibration_gmacs"))
    if value is not None:
        return value
    machine = details.get("contention") or {}
    try:
        a = float(machine["before"]["calibration_gmacs"])
        b = float(machine["after"]["calibration_gmacs"])
    except (KeyError, TypeError, ValueError):
        return None
    return math.sqrt(a * b) if a > 0 and b > 0 else None


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
        return [f"{i}. {md_escape(t)}" for i, t in enumerate(self.texts, 1)]
