"""Running one cell: a complexity, speed, accuracy or mapping measurement, returned as a
:class:`~evsmap.runner.records.CellRecord`.

Cells the machine cannot measure (a dataset not prepared, weights not given, a Jetson) become
``na`` records naming what is missing; a cell whose run raises becomes an ``error`` record with
the message. Mapping is measured per (system, sequence) in "mapping runs" (``extra/mapping/...``
records, beyond the paper's tables); Table IV's cells are then read from those runs
(:func:`~evsmap.runner.table4_reading.table4_record`), so each map is built once.
"""

from __future__ import annotations

import time
import traceback

from evsmap.errors import EvsmapError
from evsmap.interrupt import reraise_interruption
from evsmap.runner.accounting import stamp
from evsmap.runner.cell_base import base_fields, environment, now
from evsmap.runner.context import RunContext
from evsmap.runner.mapping_plan import MappingRun
from evsmap.runner.mapping_record import mapping_record
from evsmap.runner.network_cells import run_accuracy, run_complexity, run_speed
from evsmap.runner.records import CellRecord
from evsmap.tables.schema import CellSpec

RUNNERS = {"complexity": run_complexity, "speed": run_speed, "accuracy": run_accuracy}


def execute_spec(spec: CellSpec, ctx: RunContext) -> CellRecord:
    """Run one non-mapping cell, turning errors into ``error`` records."""
    from evsmap.measure.memory import mark_peak, peak_since_mark

    mark_peak()
    started, t0, began = now(), time.perf_counter(), stamp()
    try:
        record = RUNNERS[spec.kind](spec, ctx)
    except EvsmapError as exc:
        reraise_interruption(exc)
        record = CellRecord(**base_fields(spec), status="error", error=str(exc))
    except Exception as exc:  # a bug: keep the traceback in the record, go on with the run
        reraise_interruption(exc)
        record = CellRecord(**base_fields(spec), status="error",
                            error=f"{type(exc).__name__}: {exc}",
                            details={"traceback": traceback.format_exc()})
    record.started, record.seconds = started, time.perf_counter() - t0
    record.cell_peak_rss_bytes = peak_since_mark()
    record.environment = environment(ctx.threads)
    record.around = {"began": began}  # the worker adds its own instants (runner.accounting)
    return record


def execute_mapping(run: MappingRun, ctx: RunContext) -> CellRecord:
    from evsmap.measure.memory import mark_peak, peak_since_mark

    mark_peak()
    started, t0, began = now(), time.perf_counter(), stamp()
    base = run.base_fields()
    try:
        record = mapping_record(run, ctx)
    except EvsmapError as exc:
        reraise_interruption(exc)
        record = CellRecord(**base, status="error", error=str(exc))
    except Exception as exc:
        reraise_interruption(exc)
        record = CellRecord(**base, status="error", error=f"{type(exc).__name__}: {exc}",
                            details={"traceback": traceback.format_exc()})
    record.started, record.seconds = started, time.perf_counter() - t0
    record.cell_peak_rss_bytes = peak_since_mark()
    record.environment = environment(ctx.threads)
    record.around = {"began": began}  # the worker adds its own instants (runner.accounting)
    return record
