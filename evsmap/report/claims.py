"""What of the paper reproduces here: its comparative claims as ratios measured in one run.

Absolute figures compare machines (this CPU against the paper's GPU or Jetson with TensorRT).
A ratio between two systems measured the same way on the same machine compares methods, and
carries across machines. So each table gets a view relative to the paper's baseline row
(:func:`relative_markdown`), and ``index.md`` opens with the paper's claims checked as such
ratios (:func:`claims_markdown`): measured here, beside the paper's own ratio, with a verdict,
or the reason it cannot be checked. The claims themselves are the paper's, stored with its
tables (:mod:`evsmap.tables.claims`).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping

import pandas as pd

from evsmap.report.detail import verdict_rows as detail_rows
from evsmap.runner.records import CellRecord
from evsmap.tables.claims import BASELINES, CLAIMS, MATCH_TOLERANCE, Claim
from evsmap.tables.schema import PaperTable


def _cells(frame: pd.DataFrame) -> dict[tuple[str, str], dict]:
    return {(r["row"], r["column"]): r for r in frame.to_dict("records")}


def _measured(cell: Mapping | None) -> float | None:
    if cell is None or cell.get("status") != "ok":
        return None
    v = cell.get("measured")
    return None if v is None or (isinstance(v, float) and math.isnan(v)) else float(v)


def _paper(cell: Mapping | None) -> float | None:
    v = None if cell is None else cell.get("paper")
    return None if v is None or (isinstance(v, float) and math.isnan(v)) else float(v)


TIMED_UNITS = ("FPS", "Hz")
"""Units of the columns whose values are timings (the others are counts or scores: exact)."""


def _precision(cell: Mapping | None) -> float | None:
    v = None if cell is None else cell.get("rel_ci")
    return None if v is None or (isinstance(v, float) and math.isnan(v)) else float(v)


def ratio_precision(a: Mapping | None, b: Mapping | None) -> float | None:
    """The precision of a ratio of two timings: the two cells' precisions added (None when
    either has none: a count, or a record from before the timing rule)."""
    pa, pb = _precision(a), _precision(b)
    return None if pa is None or pb is None else pa + pb


def _calibration(cell: Mapping | None) -> float | None:
    v = None if cell is None else cell.get("calibration_gmacs")
    return None if v is None or (isinstance(v, float) and math.isnan(v)) or v <= 0 else float(v)


def measured_ratio(a: Mapping | None, b: Mapping | None) -> tuple[float | None, float | None]:
    """(ratio, raw ratio) of two frame cells' measured values. For timings with a calibration
    (:func:`~evsmap.measure.speed.calibrated_ratio`) the ratio is drift-corrected and the raw
    one is kept beside it; otherwise both are the plain ratio. ``(None, None)`` when either
    value is missing."""
    ma, mb = _measured(a), _measured(b)
    if ma is None or not mb:
        return None, None
    from evsmap.measure.speed import calibrated_ratio

    return calibrated_ratio(ma, _calibration(a), mb, _calibration(b)), ma / mb


def _why(cell: Mapping | None, row: str) -> str:
    if cell is None:
        return f"{row}: not in this run"
    note = str(cell.get("note") or "").strip().removeprefix("n/a - ")
    return f"{cell.get('label', row)}: {note or cell.get('status')}"


def check(claim: Claim, frame: pd.DataFrame) -> dict:
    """One claim against a table's frame (:func:`~evsmap.report.tables.table_frame`):
    ``measured`` and ``paper`` ratios, ``verdict`` ("holds", "does not hold", "cannot be
    checked here") and ``why`` when it cannot."""
    cells = _cells(frame)
    a, b = cells.get((claim.row, claim.column)), cells.get((claim.base, claim.column))
    pa, pb = _paper(a), _paper(b)
    paper = pa / pb if pa is not None and pb else None
    ma, mb = _measured(a), _measured(b)
    ratio, raw = measured_ratio(a, b)
    if ratio is None:  # ma is None or not mb
        missing = ([_why(a, claim.row)] if ma is None else []) + \
            ([_why(b, claim.base)] if not mb else [])
        return {"claim": claim.text, "measured": None, "raw": None, "paper": paper,
                "verdict": "cannot be checked here", "why": "; ".join(missing)}
    if claim.mode == "higher":
        holds = ratio > 1.0
    elif claim.mode == "lower":
        holds = ratio < 1.0
    else:
        holds = paper is not None and abs(ratio / paper - 1.0) <= MATCH_TOLERANCE
    flagged = any(isinstance(c.get("timing_flag"), str) and c.get("timing_flag")
                  for c in (a, b) if c is not None)
    return {"claim": claim.text, "measured": ratio, "raw": raw, "paper": paper,
            "precision": ratio_precision(a, b),
            "timed": any(c is not None and c.get("unit") in TIMED_UNITS for c in (a, b)),
            "verdict": "holds" if holds else "does not hold",
            "why": "a timing in it is flagged (~)" if flagged else ""}


def checked_claims(frames: Mapping[str, pd.DataFrame]) -> list[dict]:
    """:func:`check` of each claim of :data:`CLAIMS` whose table is in ``frames``."""
    return [check(c, frames[c.table]) for c in CLAIMS if c.table in frames]


def claims_markdown(frames: Mapping[str, pd.DataFrame],
                    extras: Iterable[CellRecord] = (),
                    detail: Iterable[CellRecord] = ()) -> list[str]:
    """``index.md``'s opening section: each claim of :data:`CLAIMS` whose table is in the run,
    then the map-size claim on the extra sequences (the synthetic room, TUM), then the
    semantic-detail claim on ScanNet (``detail``: :mod:`evsmap.report.detail`'s records)."""
    rows = checked_claims(frames)
    extras, detail = list(extras), list(detail)
    if not rows and not extras and not detail:
        return []
    out = ["## What reproduces here", "",
           "The paper's comparative claims, each as a ratio of two systems measured the same "
           "way in this run (ratios carry across machines; this CPU against the paper's GPU or "
           "Jetson does not). A ratio of two timings divides each by the calibration matmul "
           "timed around it first, so the machine running faster or slower between the two "
           "does not move it; the plain ratio follows in brackets. Its precision is the two "
           "timings' (each the half-width of its median's 95 % interval) added: another idle "
           "run should land within it.", "",
           "| claim | measured ratio | precision | paper's ratio | here |",
           "|---|---:|---:|---:|---|"]
    out += ["| " + " | ".join(row) + " |" for row in claim_rows(rows, extras, detail)]
    out.append("")
    return out


def claim_rows(checked: Iterable[dict], extras: Iterable[CellRecord] = (),
               detail: Iterable[CellRecord] = (),
               readings: Iterable[str] | None = None) -> list[tuple[str, ...]]:
    """The claims table's rows as cells (claim, measured ratio, precision, paper's ratio,
    verdict), Markdown-escaped: the :func:`check` results ``checked``, then the map-size claim
    under each of ``readings`` (default: every reading) and the semantic-detail claim."""
    out: list[tuple[str, ...]] = []
    for r in checked:
        measured = "-" if r["measured"] is None else f"{r['measured']:.2f}x"
        if r.get("raw") is not None and f"{r['raw']:.2f}" != f"{r['measured']:.2f}":
            measured += f" (plain {r['raw']:.2f}x)"
        paper = "-" if r["paper"] is None else f"{r['paper']:.2f}x"
        verdict = r["verdict"] + (f" ({_short(r['why'])})" if r["why"] else "")
        precision = ("-" if r["measured"] is None else "exact" if not r.get("timed") else
                     "-" if r.get("precision") is None else f"+-{100 * r['precision']:.1f} %")
        out.append((r["claim"], measured, precision, paper, verdict))
    from evsmap.report.map_size import verdict_rows

    out += [split_row(row) for row in verdict_rows(extras, readings)]
    out += [split_row(row) for row in detail_rows(detail)]
    return out


def split_row(row: str) -> tuple[str, ...]:
    """A Markdown table row's cells (an escaped ``\\|`` stays inside its cell)."""
    import re

    return tuple(c.strip() for c in re.split(r"(?<!\\)\|", row.strip())[1:-1])


def _short(text: str, limit: int = 140) -> str:
    text = " ".join(text.split()).replace("|", "\\|")
    return text if len(text) <= limit else text[:limit - 3] + "..."


def relative_markdown(table: PaperTable, frame: pd.DataFrame) -> list[str]:
    """The table relative to its baseline row (:data:`BASELINES`): for every implemented row
    and numeric column, ``measured ratio / paper's ratio``."""
    base = BASELINES.get(table.id)
    if base is None:
        return []
    cells = _cells(frame)
    columns = [c for c in table.columns if c.kind != "flag"]
    base_label = next((r.label for r in table.rows if r.id == base), base)
    out = [f"## Relative to {base_label} (the paper's baseline row)", "",
           f"Each cell: this row / {base_label} measured here, then the same ratio of the "
           f"paper's figures. Ratios of systems measured the same way compare methods; they "
           f"carry across machines where absolute figures do not. Speeds and rates are each "
           f"divided by the calibration matmul timed around them before the ratio is taken "
           f"(drift-corrected).", "",
           "| System | " + " | ".join(c.header for c in columns) + " |",
           "|---|" + "|".join("---:" for _ in columns) + "|"]
    for system in table.rows:
        if not system.implemented or system.id == base:
            continue
        line = [system.label]
        for col in columns:
            a, b = cells.get((system.id, col.id)), cells.get((base, col.id))
            ratio, _ = measured_ratio(a, b)
            pa, pb = _paper(a), _paper(b)
            m = f"{ratio:.2f}x" if ratio is not None else "-"
            p = f"{pa / pb:.2f}x" if pa is not None and pb else "-"
            line.append(f"{m} / {p}" if (m, p) != ("-", "-") else "-")
        out.append("| " + " | ".join(line) + " |")
    return out + [""]


__all__ = ["BASELINES", "CLAIMS", "MATCH_TOLERANCE", "Claim", "check", "checked_claims",
           "claim_rows", "claims_markdown", "measured_ratio", "relative_markdown", "split_row"]
