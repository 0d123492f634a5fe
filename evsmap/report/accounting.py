"""Where the run's wall time went: ``index.md``'s "Where the time went" section, from
``run.json``'s ``time_accounting`` and the timed cells' ``around`` (:mod:`evsmap.runner.
accounting`)."""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

from evsmap.runner.accounting import AROUND, PHASES
from evsmap.runner.records import CellRecord

AROUND_WORDS = {
    "start_s": "process spawn and imports",
    "setup_s": "the worker's setup (context, the cell's spec)",
    "cell_s": "the cells themselves",
    "finish_s": "after the cell in the worker (memory, environment)",
    "return_s": "the record's way back and the process's end",
    "retry_s": "another try of a whole process on a busy machine, with its pause",
}
"""What each part of the time around a timed cell is, in words."""


def around_totals(records: Iterable[CellRecord]) -> dict[str, dict[str, float]]:
    """Per phase of timed cells (``timed cells``: speed; ``mapping runs``), the sum of each
    part of :data:`evsmap.runner.accounting.AROUND` and of the driver's wait (``wall_s``)."""
    out: dict[str, dict[str, float]] = {}
    for rec in records:
        if not rec.around or "wall_s" not in rec.around or "pooled" in rec.around:
            continue
        group = out.setdefault("mapping runs" if rec.kind == "mapping" else "timed cells", {})
        for key in ("wall_s", *AROUND):
            group[key] = group.get(key, 0.0) + float(rec.around.get(key, 0.0))
    return out


def accounting_markdown(accounting: dict[str, Any] | None,
                        records: list[CellRecord]) -> list[str]:
    """The section: the run's phases as a table adding up to its wall time, then what the
    timed phases' time holds (empty for a run made before the accounting existed)."""
    if not accounting or not accounting.get("phases"):
        return []
    wall = float(accounting["wall_s"])
    phases = accounting["phases"]
    out = ["## Where the time went", "",
           f"The run took **{wall / 60:.1f} min** from its process's start to `run.json`'s last "
           f"write (the report's build follows; the command prints its time). Every phase:", "",
           "| phase | min | share |", "|---|---:|---:|"]
    if accounting.get("estimate_s"):
        estimate = float(accounting["estimate_s"])
        out[2:2] = [f"Its start line estimated **{estimate / 60:.1f} min** "
                    f"({100 * (estimate / wall - 1):+.0f} % of the wall time).", ""]
    for name in PHASES:
        if name in phases:
            out.append(f"| {name} | {phases[name] / 60:.2f} | {_share(phases[name], wall)} |")
    unaccounted = float(accounting.get("unaccounted_s", 0.0))
    out.append(f"| in no phase | {unaccounted / 60:.2f} | {_share(unaccounted, wall)} |")
    out.append("")
    for group, totals in around_totals(records).items():
        waited = totals["wall_s"]
        parts = ", ".join(f"{AROUND_WORDS[k]} {totals[k] / 60:.2f} min"
                          for k in AROUND if totals.get(k))
        rest = waited - sum(totals.get(k, 0.0) for k in AROUND)
        out.append(f"- The {group}: the run waited {waited / 60:.2f} min for them: {parts}"
                   + (f"; {rest / 60:.2f} min in none of these" if abs(rest) > 1.0 else "")
                   + ".")
    out.append("")
    return out


def _share(seconds: float, wall: float) -> str:
    return f"{100 * seconds / wall:.1f} %" if wall > 0 else "-"
