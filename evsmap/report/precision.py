"""How far the run's speed figures can be trusted, and what the run cost: ``index.md``'s
"Timing precision" section.

Each speed cell keeps the precision its median reached (the half-width of its confidence
interval over the median, :mod:`evsmap.measure.timing_policy`) and why it stopped. The section
states the rule, the distribution of the precision over the cells, the cells that stopped on
their budget, and the run's time, exports and peak memory per cell, so a reader knows which
ratios in "What reproduces here" can move between two runs and by how much.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import numpy as np

from evsmap.runner.records import CellRecord


def speed_precision(records: Iterable[CellRecord]) -> list[dict[str, Any]]:
    """One line per measured speed cell: key, precision (``rel_ci``), why it stopped, passes,
    seconds, export seconds (None: cached or none), peak RSS."""
    lines = []
    for rec in records:
        if rec.kind != "speed" or rec.status != "ok":
            continue
        details = rec.details or {}
        export = details.get("export") or {}
        lines.append({"key": rec.key, "label": rec.label, "rel_ci": details.get("rel_ci"),
                      "stopped": details.get("stopped"), "runs": details.get("runs"),
                      "seconds": rec.seconds, "export_s": export.get("export_s"),
                      "size_free": export.get("size_free"),
                      "peak_rss_bytes": rec.cell_peak_rss_bytes or None})
    return lines


def precision_markdown(records: list[CellRecord], policy: dict[str, Any] | None) -> list[str]:
    """The section (empty when the run timed no speed cell)."""
    lines = speed_precision(records)
    if not lines:
        return []
    out = ["## Timing precision", ""]
    if policy:
        out.append(f"Every speed cell follows one rule: after at least {policy['warmup']} "
                   f"warm-up pass(es) and {policy['warmup_s']:g} s, passes are timed until the "
                   f"median's {policy['confidence']:.0%} confidence interval (bootstrap) is "
                   f"within +-{policy['target_rel_ci']:.0%}, at least {policy['min_runs']} "
                   f"passes, stopping after {policy['budget_s']:g} s of timed passes (or "
                   f"after {policy['max_runs']} passes) with the precision reached.")
        out.append("")
    rel = np.array([x["rel_ci"] for x in lines if x["rel_ci"] is not None], dtype=float)
    if rel.size:
        q50, q90 = np.percentile(rel, [50, 90]) * 100
        met = int(sum(x["stopped"] == "precision" for x in lines))
        out.append(f"- Precision of the {rel.size} speed cells' medians: median +-{q50:.1f} %, "
                   f"90th percentile +-{q90:.1f} %, worst +-{rel.max() * 100:.1f} %; "
                   f"{met} reached the target, {rel.size - met} stopped on "
                   f"{'its' if rel.size - met == 1 else 'their'} budget.")
        budget = [x for x in lines if x["stopped"] == "budget"]
        if budget:
            worst = sorted(budget, key=lambda x: -(x["rel_ci"] or 0))[:8]
            out.append("- Stopped on their budget, with the precision reached: "
                       + ", ".join(f"{x['label']} {_size(x['key'])} +-{x['rel_ci'] * 100:.1f} %"
                                   for x in worst) + (" ..." if len(budget) > 8 else ""))
        out.append("- A ratio of two speeds can move between two idle runs by about the sum "
                   "of its two cells' precisions.")
    exported = [x for x in lines if x["export_s"]]
    free = sum(bool(x["size_free"]) for x in lines)
    if exported or free:
        out.append(f"- ONNX exports: {len(exported)} made in this run "
                   f"({sum(x['export_s'] for x in exported):.0f} s), the others from the cache; "
                   f"{free} of {len(lines)} cells timed a size-free export (one per network).")
    peaks = [(x["peak_rss_bytes"], x["label"], x["key"]) for x in lines if x["peak_rss_bytes"]]
    all_peaks = [(r.cell_peak_rss_bytes, r.label, r.key) for r in records
                 if r.cell_peak_rss_bytes]
    if all_peaks:
        top = max(all_peaks)
        out.append(f"- Peak memory of a cell: {top[0] / 2**30:.2f} GiB ({top[1]}, `{top[2]}`)"
                   + (f"; of a speed cell: {max(peaks)[0] / 2**30:.2f} GiB ({max(peaks)[1]} "
                      f"{_size(max(peaks)[2])})" if peaks else ""))
    seconds = sum(r.seconds for r in records)
    out.append(f"- Time in the cells: {seconds / 60:.1f} min (speed cells "
               f"{sum(x['seconds'] for x in lines) / 60:.1f} min).")
    out.append("")
    return out


def _size(key: str) -> str:
    """``640x480`` from a cell key (``.../speed@640x480[fps]``)."""
    if "@" not in key:
        return ""
    return key.split("@", 1)[1].split("[", 1)[0].split("#", 1)[0]
