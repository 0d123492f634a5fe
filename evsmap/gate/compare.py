"""Hold gate measurements against a baseline: verdicts and the table that names them.

Rules (``docs/gates.md``):

* every exact count (any key of a baseline entry but ``time_ratio``, ``peak_rss_bytes`` and
  ``context``) must be equal;
* ``time_ratio`` fails above ``baseline * (1 + time)`` (15 % by default);
* ``peak_rss_bytes`` fails above ``baseline * (1 + memory)`` (10 %) when it also grew by more
  than ``memory_slack_bytes`` (2 MiB: the page and allocator granularity of a small workload);
* a figure below ``baseline * (1 - threshold)`` is ``better``: it passes, with a hint to
  ``--update``;
* a workload of the baseline that did not run (missing data, an error) fails; a workload the
  baseline does not have is ``new``: it passes, with the same hint;
* on a machine of another kind than the baseline's (:func:`evsmap.gate.baseline.machine_kind`: CPU
  model and vector extensions, cores, library versions) only the counts that do not depend on
  floating point are held: time ratios, peaks and the :data:`MACHINE_DEPENDENT` counts are
  shown as ``not compared`` - a baseline holds on machines of its own kind; record one there
  with ``--update``.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import asdict, dataclass
from typing import Any

TIME_THRESHOLD = 0.15
MEMORY_THRESHOLD = 0.10
MEMORY_SLACK_BYTES = 2 * 1024 * 1024
MEASURED_KEYS = ("time_ratio", "peak_rss_bytes")
NOT_COUNTS = frozenset({*MEASURED_KEYS, "context"})
MACHINE_DEPENDENT = frozenset({"output_sha256", "nodes", "leaves", "file_bytes", "file_sha256"})
"""Counts computed through floating point (a network's labels, a map's pruning and file):
bit-exact on one machine kind, but another CPU's vector kernels may round differently."""


@dataclass(frozen=True)
class Thresholds:
    time: float = TIME_THRESHOLD
    memory: float = MEMORY_THRESHOLD
    memory_slack_bytes: int = MEMORY_SLACK_BYTES


@dataclass(frozen=True)
class Row:
    """One line of the verdict table: ``workload``, ``measure`` (``time_ratio``,
    ``peak_rss_bytes``, a count's key, or ``-`` for the workload as a whole), ``baseline`` and
    ``now`` (``None`` where absent), ``change`` (relative, measured figures only) and
    ``verdict``: ``ok``, ``better``, ``new``, ``FAIL``."""

    workload: str
    measure: str
    baseline: Any
    now: Any
    change: float | None
    verdict: str
    why: str = ""

    @property
    def failed(self) -> bool:
        return self.verdict == "FAIL"

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


def entry_of(record: dict[str, Any]) -> dict[str, Any]:
    """The baseline entry of one worker record: the two measured figures, the counts flat
    beside them and the figures they came from under ``context``."""
    ctx = {k: record[k] for k in ("workload_ms", "calibration", "calibration_ms",
                                  "calibration_parts_ms",
                                  "time_ratio_rel_iqr", "pairs", "idle_rss_bytes",
                                  "peak_scope", "threads", "cpus", "processes",
                                  "description") if k in record}
    return {"time_ratio": record["time_ratio"], "peak_rss_bytes": record["peak_rss_bytes"],
            **record.get("counts", {}), "context": ctx}


def _verdict(key: str, change: float, grown_bytes: float, th: Thresholds) -> str:
    """``FAIL``, ``better`` or ``ok`` for a relative ``change`` of ``key``; a peak must also
    have moved by more than the slack (``grown_bytes``, negative when it shrank)."""
    limit = th.time if key == "time_ratio" else th.memory
    moved = key == "time_ratio" or abs(grown_bytes) > th.memory_slack_bytes
    if change > limit and moved:
        return "FAIL"
    if change < -limit and moved:
        return "better"
    return "ok"


def _measured_row(name: str, key: str, base: float, now: float, th: Thresholds) -> Row:
    change = now / base - 1.0 if base > 0 else (0.0 if now == base else math.inf)
    verdict = _verdict(key, change, now - base, th)
    limit = th.time if key == "time_ratio" else th.memory
    why = f"more than {limit:.0%} above the baseline" if verdict == "FAIL" else ""
    return Row(name, key, base, now, change, verdict, why)


def compare(baseline: dict[str, dict[str, Any]], measured: dict[str, dict[str, Any]],
            thresholds: Thresholds | None = None, *, same_machine: bool = True) -> list[Row]:
    """Verdict rows of ``measured`` (workload -> worker record) against ``baseline``
    (workload -> entry, the ``"workloads"`` object of a baseline file). Workloads are the
    union of both; pass only the selected part of the baseline. ``same_machine=False``: the
    baseline is of another machine kind (see the module docstring)."""
    th = thresholds or Thresholds()
    other = "another machine kind than the baseline's"
    rows: list[Row] = []
    for name in sorted(set(baseline) | set(measured)):
        base, rec = baseline.get(name), measured.get(name)
        if rec is None or "error" in rec or "skipped" in rec:
            why = "not measured" if rec is None else _not_measured(rec)
            if base is None:  # neither baselined nor measurable here: say so, do not fail
                rows.append(Row(name, "-", None, None, None, "skipped", why))
            else:
                rows.append(Row(name, "-", "baselined", None, None, "FAIL", why))
            continue
        if base is None:
            rows.append(Row(name, "-", None, "measured", None, "new",
                            "not in the baseline"))
            now = entry_of(rec)
            for key in MEASURED_KEYS:
                rows.append(Row(name, key, None, now[key], None, "new"))
            continue
        now = entry_of(rec)
        was = base.get("context", {}).get("calibration", "compute")
        for key in MEASURED_KEYS:
            row = _measured_row(name, key, float(base[key]), float(now[key]), th)
            if key == "time_ratio" and was != now["context"].get("calibration", "compute"):
                row = Row(name, key, row.baseline, row.now, row.change, "FAIL",
                          f"divided by another calibration than the baseline's ({was}): "
                          f"record the baseline again (--update)")
            if not same_machine:
                row = Row(name, key, row.baseline, row.now, row.change, "not compared", other)
            rows.append(row)
        rows += _count_rows(name, base, now, same_machine=same_machine)
    return rows


def _not_measured(record: dict[str, Any]) -> str:
    """Why a worker record holds no figures: its error, else why it was skipped."""
    return record.get("error") or record.get("skipped") or ""


def _count_rows(name: str, base: dict[str, Any], now: dict[str, Any], *,
                same_machine: bool) -> list[Row]:
    rows = []
    for key in sorted(set(base) - NOT_COUNTS | set(now) - NOT_COUNTS):
        b, n = base.get(key), now.get(key)
        if b == n:
            continue
        if not same_machine and key in MACHINE_DEPENDENT and b is not None and n is not None:
            rows.append(Row(name, key, b, n, None, "not compared",
                            "another machine kind than the baseline's"))
            continue
        rows.append(Row(name, key, b, n, None, "FAIL",
                        "an exact count changed" if b is not None and n is not None
                        else "a count is missing on one side"))
    return rows


def compare_paired(pairs: dict[str, list[tuple[dict[str, Any], dict[str, Any]]]],
                   thresholds: Thresholds | None = None, *,
                   only_reference: Iterable[str] = (),
                   only_here: dict[str, dict[str, Any]] | None = None) -> list[Row]:
    """Verdict rows of a paired run: ``pairs`` maps a workload to its (reference, this tree)
    worker records, measured back to back on the same CPU. The reference column holds the
    reference's median, ``now`` this tree's, and ``change`` the median over the pairs of this
    tree's figure over the reference's: the verdict comes from the paired ratios, with the
    thresholds of :func:`compare`. Every count is held (both sides ran on this machine). A
    workload this tree could not measure (an error, missing data) fails, as a baselined one
    does.
    Workloads in ``only_reference`` (the reference has them, this tree does not) fail; those in
    ``only_here`` (workload -> this tree's record) are ``new``."""
    from evsmap.gate.run import combine

    th = thresholds or Thresholds()
    rows: list[Row] = [Row(n, "-", "measured", None, None, "FAIL",
                           "the reference has this workload, this tree does not")
                       for n in sorted(only_reference)]
    for name in sorted(pairs):
        refs, nows = [p[0] for p in pairs[name]], [p[1] for p in pairs[name]]
        ref, now = combine(refs), combine(nows)
        if "error" in now or "skipped" in now:  # the reference has it: like a baselined one
            rows.append(Row(name, "-", "measured", None, None, "FAIL", _not_measured(now)))
        elif "error" in ref or "skipped" in ref:
            rows.append(Row(name, "-", None, "measured", None, "not compared",
                            "the reference could not measure it: "
                            + str(ref.get("error") or ref.get("skipped"))))
        else:
            rows += _paired_rows(name, refs, nows, ref, now, th)
    rows += [Row(r.workload, r.measure, r.baseline, r.now, r.change, r.verdict,
                 r.why.replace("not in the baseline", "not in the reference"))
             for r in compare({}, only_here or {}, th)]
    return rows


def _paired_rows(name: str, refs: list[dict[str, Any]], nows: list[dict[str, Any]],
                 ref: dict[str, Any], now: dict[str, Any], th: Thresholds) -> list[Row]:
    import numpy as np

    rows = []
    same_calibration = ref.get("calibration") == now.get("calibration")
    time_key = "time_ratio" if same_calibration else "workload_ms"
    for key in MEASURED_KEYS:
        pick = time_key if key == "time_ratio" else key
        pairs = list(zip(refs, nows, strict=True))
        ratios = [b[pick] / a[pick] if a[pick] > 0 else math.inf for a, b in pairs]
        change = float(np.median(ratios)) - 1.0
        grown = float(np.median([b[pick] - a[pick] for a, b in pairs]))
        verdict = _verdict(key, change, grown, th)
        limit = th.time if key == "time_ratio" else th.memory
        why = f"more than {limit:.0%} above the reference" if verdict == "FAIL" else ""
        if key == "time_ratio" and not same_calibration:
            why = (f"the two sides divide by other calibrations ({ref.get('calibration')}, "
                   f"{now.get('calibration')}): judged on raw times. {why}").strip()
        rows.append(Row(name, key, ref[key], now[key], change, verdict, why))
    rows += [Row(r.workload, r.measure, r.baseline, r.now, r.change, r.verdict,
                 r.why.replace("an exact count changed", "an exact count differs from the "
                               "reference's"))
             for r in _count_rows(name, entry_of(ref), entry_of(now), same_machine=True)]
    return rows


def _fmt(measure: str, value: Any) -> str:
    if value is None:
        return "-"
    if measure == "time_ratio" and isinstance(value, (int, float)):
        return f"{value:.4g}"
    if measure == "peak_rss_bytes" and isinstance(value, (int, float)):
        return f"{value / 2**20:.1f} MiB"
    if isinstance(value, int):
        return f"{value:,}"
    return str(value)


def table(rows: list[Row], *, all_rows: bool = True, against: str = "baseline") -> str:
    """The verdict table as Markdown: workload, measure, ``against`` (the baseline or the
    reference), now, change, verdict."""
    shown = rows if all_rows else [r for r in rows if r.verdict != "ok"]
    lines = [f"| workload | measure | {against} | now | change | verdict |",
             "|---|---|---|---|---|---|"]
    for r in shown:
        change = "-" if r.change is None else f"{r.change:+.1%}"
        verdict = r.verdict + (f": {r.why}" if r.why and r.verdict != "ok" else "")
        lines.append(f"| {r.workload} | {r.measure} | {_fmt(r.measure, r.baseline)} | "
                     f"{_fmt(r.measure, r.now)} | {change} | {verdict} |")
    return "\n".join(lines)


def summary(rows: list[Row], *, paired: bool = False) -> tuple[bool, str]:
    """(passed, one paragraph): how many workloads failed and which, and the ``--update``
    hint when some figure is clearly better or a workload is new (``paired``: better than
    or new to the reference commit measured beside this tree)."""
    failed = sorted({r.workload for r in rows if r.failed})
    better = sorted({r.workload for r in rows if r.verdict in ("better", "new")})
    workloads = len({r.workload for r in rows})
    lines = []
    if failed:
        lines.append(f"gate FAILED: {len(failed)} of {workloads} workloads regressed or "
                     f"changed: {', '.join(failed)}")
    else:
        lines.append(f"gate passed: {workloads} workloads within the thresholds")
    if any(r.verdict == "not compared" and r.why.startswith("another machine kind")
           for r in rows):
        lines.append("WARNING: this machine is of another kind than the baseline's: time "
                     "ratios, peaks and floating-point counts were not compared (record a "
                     "baseline on this kind of machine with `evsmap gate --update`)")
    if better and paired:
        lines.append(f"{len(better)} workloads are clearly better than or new to the reference "
                     f"({', '.join(better)})")
    elif better:
        lines.append(f"{len(better)} workloads are clearly better than or new to the baseline "
                     f"({', '.join(better)}): run `evsmap gate --update` to record them")
    return not failed, "\n".join(lines)
