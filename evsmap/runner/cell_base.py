"""What every cell record carries: the machine's environment (CPU, threads, library versions,
git commit, lock status), the time it started, the fields a table cell names, ``na`` records,
and the pauses before a contended timing is taken again."""

from __future__ import annotations

from datetime import UTC, datetime
from typing import Any

from evsmap.environment import collect_environment
from evsmap.lock import lock_status
from evsmap.runner.context import RunContext
from evsmap.runner.records import CellRecord, needs_text
from evsmap.tables.schema import CellSpec, load_tables


def environment(threads: int | None = None) -> dict[str, Any]:
    """:func:`evsmap.environment.collect_environment` and the lock's status."""
    env = collect_environment(threads)
    env["lock"] = lock_status()
    return env


def now() -> str:
    return datetime.now(UTC).isoformat(timespec="seconds")


def base_fields(spec: CellSpec) -> dict[str, Any]:
    return {"key": spec.key, "table": spec.table, "row": spec.row, "label": spec.label,
            "kind": spec.kind, "metrics": list(spec.metrics), "inputs": spec_inputs(spec)}


def spec_inputs(spec: CellSpec) -> dict[str, Any]:
    return {"segmenter": spec.segmenter.spec if spec.segmenter else None,
            "updater": spec.updater.spec if spec.updater else None,
            "datasets": list(spec.datasets), "split": spec.split,
            "input_size": list(spec.input_size) if spec.input_size else None,
            "resolution": spec.resolution, "hardware": spec.hardware,
            "config_key": spec.config_key}


def error_record(base: dict[str, Any], exc: BaseException, t0: float) -> CellRecord:
    """The record of a pass's item that failed (the pass goes on with the next one): its one-line
    error, the traceback in ``details``, the seconds since ``perf_counter`` read ``t0``. An
    interruption (Ctrl-C, a stop) is raised again instead."""
    import time
    import traceback

    from evsmap.errors import EvsmapError
    from evsmap.interrupt import reraise_interruption

    reraise_interruption(exc)
    text = str(exc) if isinstance(exc, EvsmapError) else f"{type(exc).__name__}: {exc}"
    return CellRecord(**base, status="error", error=text,
                      details={"traceback": traceback.format_exc()},
                      seconds=time.perf_counter() - t0)


def na_record(spec: CellSpec, needs: list[str], ctx: RunContext) -> CellRecord:
    return CellRecord(**base_fields(spec), status="na", needs=list(needs), reason=needs_text(needs),
                      started=now())


def column_quantities(spec: CellSpec) -> dict[str, str]:
    table = load_tables()[spec.table]
    return {col: table.column(col).quantity for col in spec.metrics}


STRICT_PAUSE_S = 20.0
"""``--strict-timing``: seconds to wait before timing a contended cell a second time."""
RETRY_PAUSE_S = 3.0
"""Without ``--strict-timing``: the same, shorter (the cell is flagged if still contended)."""
