"""Scheduling a run: expand the tables into cells, decide what can be measured here, run the
cells and store each record as it finishes.

Order and isolation:

1. Cells that cannot be measured here (``needs``) are recorded as ``na`` at once.
2. Complexity and accuracy cells run in a process pool (``workers``); cells with the same
   configuration (``CellSpec.config_key``: e.g. FEAGNet-V2's parameters in Tables I and III) are
   measured once and recorded under each key.
3. Timing cells (speed, and the mapping runs behind Table IV) then run one at a time, each in a
   fresh interpreter (``spawn``, one task per process), so no cell inherits another's warm
   caches, threads or memory, and nothing else of the run competes for the cores.
4. Table IV's cells are read from the mapping runs.

With ``resume`` the records already ``ok`` are kept and everything else is run again; ``force``
reruns everything.
"""

from __future__ import annotations

import multiprocessing
import time
from collections.abc import Callable, Iterable
from concurrent.futures import Executor, Future, ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from evsmap.fileio import atomic_write_text
from evsmap.runner.context import RunContext
from evsmap.runner.execute import (
    MappingRun,
    environment,
    execute_mapping,
    execute_spec,
    mapping_runs,
    na_record,
    table4_record,
)
from evsmap.runner.records import CellRecord, RecordStore, needs_text
from evsmap.tables.schema import CellSpec, expand, load_tables

TABLES = ("table1", "table2", "table3", "table4")
QUICK_MAX_PIXELS = 1024 * 512
"""``--quick`` skips speed cells above this input size (ESANet at 2048x1024 takes seconds per
frame); they are recorded as not run."""


@dataclass
class Plan:
    """What a run will do: the table cells, the mapping runs, and the sequences mapped."""

    specs: list[CellSpec]
    runs: list[MappingRun]
    sequences: list[str]
    skipped: list[tuple[str, str]] = field(default_factory=list)  # (key, why)

    @property
    def keys(self) -> list[str]:
        return [s.key for s in self.specs] + [r.key for r in self.runs]


def plan(ctx: RunContext, tables: Iterable[str] = TABLES) -> Plan:
    """Expand ``tables`` against what is available here."""
    loaded = load_tables()
    specs: list[CellSpec] = []
    for tid in tables:
        first = expand(loaded[tid])
        requires = sorted({r for s in first for r in s.requires})
        specs += expand(loaded[tid], available=ctx.available(requires))
    skipped = []
    if ctx.quick:
        keep = []
        for s in specs:
            if s.kind == "speed" and s.input_size and \
                    s.input_size[0] * s.input_size[1] > QUICK_MAX_PIXELS and not s.needs:
                skipped.append((s.key, "skipped by --quick (input above 1024x512)"))
            else:
                keep.append(s)
        specs = keep
    sequences = []
    if "table4" in tables:
        sequences = ["synthetic"] + [
            d for d in ("tum", "rtabmap", "asl", "ours1", "ours2")
            if ctx.dataset_path(d) is not None]
    runs = mapping_runs(sequences, ctx.voxel_size) if sequences else []
    return Plan(specs, runs, sequences, skipped)


# ------------------------------------------------------------------ workers (top level: picklable)
def _spec_worker(table: str, key: str, ctx_data: dict[str, Any]) -> dict[str, Any]:
    ctx = RunContext(**ctx_data)
    spec = next(s for s in expand(load_tables()[table]) if s.key == key)
    return execute_spec(spec, ctx).as_dict()


def _mapping_worker(run: MappingRun, ctx_data: dict[str, Any]) -> dict[str, Any]:
    return execute_mapping(run, RunContext(**ctx_data)).as_dict()


def _fresh_executor() -> Executor:
    """One task per fresh interpreter, one at a time."""
    return ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("spawn"),
                               max_tasks_per_child=1)


def _severity(record: CellRecord) -> float | None:
    from evsmap.measure.contention import severity

    machine = record.details.get("contention") if record.status == "ok" else None
    return None if not machine else severity(machine)


def _timed_mapping(run: MappingRun, ctx: RunContext,
                   fresh: Callable[[], Executor]) -> CellRecord:
    """A mapping run in a fresh process. One that the calibration says ran on a busy machine is
    run once more after a pause (as a contended speed cell is), and the less contended of the
    two kept; with ``--strict-timing`` one still contended is recorded as not measured."""
    from evsmap.runner.execute import RETRY_PAUSE_S, STRICT_PAUSE_S

    def once() -> CellRecord:
        with fresh() as ex:
            return CellRecord.from_dict(ex.submit(_mapping_worker, run, ctx.as_dict()).result())

    from evsmap.measure.contention import describe

    record = once()
    first = _severity(record)
    if first is None or not record.details["contention"]["contended"]:
        return record
    why = describe(record.details["contention"])
    time.sleep(STRICT_PAUSE_S if ctx.strict_timing else RETRY_PAUSE_S)
    again = once()
    if (_severity(again) or float("inf")) < first:
        record = again
    machine = record.details["contention"]
    if ctx.strict_timing and machine["contended"]:
        return CellRecord(
            key=record.key, table=record.table, row=record.row, label=record.label,
            kind=record.kind, metrics=list(record.metrics), status="na",
            needs=["an idle machine"], inputs=dict(record.inputs), details=dict(record.details),
            reason=f"n/a - --strict-timing: the machine was busy in both tries "
                   f"({describe(machine)}); rerun when it is idle",
            environment=record.environment)
    record.notes.append(f"timed twice: the first try was {why}; kept the less contended")
    return record


def _unlabelled(ctx: RunContext, sequence: str, cache: dict[str, bool]) -> bool:
    if sequence not in cache:
        from evsmap.runner.execute import open_mapping_sequence

        seq = open_mapping_sequence(ctx, sequence)
        cache[sequence] = len(seq) == 0 or seq.frame(0).labels is None
    return cache[sequence]


def run_matrix(ctx: RunContext, the_plan: Plan, *, workers: int = 1, resume: bool = False,
               force: bool = False,
               on_record: Callable[[CellRecord], None] | None = None,
               pool: Callable[[int], Executor] | None = None,
               fresh: Callable[[], Executor] | None = None) -> list[CellRecord]:
    """Run every cell of ``the_plan`` not already done; returns all records of the plan.

    ``pool(workers)`` and ``fresh()`` make the executors of the pooled and the timing cells
    (default: spawned process pools; tests pass in-process ones)."""
    pool = pool or (lambda n: ProcessPoolExecutor(
        max_workers=max(1, n), mp_context=multiprocessing.get_context("spawn")))
    fresh = fresh or _fresh_executor
    store = RecordStore(ctx.out)
    done: dict[str, CellRecord] = {}
    if resume and not force:
        for key in the_plan.keys:
            rec = store.get(key)
            if rec is not None and rec.status == "ok":
                done[key] = rec

    def keep(record: CellRecord) -> None:
        store.write(record)
        done[record.key] = record
        if on_record is not None:
            on_record(record)

    env = None
    # 1. what cannot run here
    todo: list[CellSpec] = []
    for spec in the_plan.specs:
        if spec.key in done or spec.kind == "mapping":
            continue
        if spec.needs:
            rec = na_record(spec, list(spec.needs), ctx)
            rec.environment = env = env or environment(ctx.threads)
            keep(rec)
        else:
            todo.append(spec)

    # 2. complexity and accuracy in a pool, once per configuration
    pooled = [s for s in todo if not s.fresh_process]
    timed = [s for s in todo if s.fresh_process]
    by_config: dict[str, list[CellSpec]] = {}
    for spec in pooled:
        by_config.setdefault(spec.config_key, []).append(spec)
    if by_config:
        with pool(workers) as ex:
            futures: dict[Future, list[CellSpec]] = {
                ex.submit(_spec_worker, group[0].table, group[0].key, ctx.as_dict()): group
                for group in by_config.values()}
            for fut in as_completed(futures):
                group = futures[fut]
                first = CellRecord.from_dict(fut.result())
                for spec in group:
                    keep(_copy_for(first, spec))

    # 3. timing cells, each in a fresh process, one at a time
    for spec in timed:
        with fresh() as ex:
            keep(CellRecord.from_dict(
                ex.submit(_spec_worker, spec.table, spec.key, ctx.as_dict()).result()))
    labels_cache: dict[str, bool] = {}
    for run in the_plan.runs:
        if run.key in done:
            continue
        if run.segmenter is not None and \
                ctx.weights_path(run.segmenter.spec, "nyuv2") is None and \
                _unlabelled(ctx, run.sequence, labels_cache):
            need = f"weights:{run.segmenter.spec}@nyuv2"
            rec = CellRecord(
                key=run.key, table="extra", row=run.row, label=run.label, kind="mapping",
                metrics=[], status="na", needs=[need],
                reason=needs_text([need]) + f" ({run.sequence} has no ground-truth labels for "
                                            f"the oracle)",
                inputs={"sequence": run.sequence, "voxel_size": run.voxel_size,
                        "updater": run.updater.spec, "segmenter": run.segmenter.spec})
            rec.environment = env = env or environment(ctx.threads)
            keep(rec)
            continue
        keep(_timed_mapping(run, ctx, fresh))

    # 4. Table IV from the mapping runs
    runs = {r.key: done[r.key] for r in the_plan.runs if r.key in done}
    for spec in the_plan.specs:
        if spec.kind != "mapping" or spec.key in done:
            continue
        # a map size needs its sequence; the rate is measured on whichever sequence the system
        # could map (weights are resolved by the runs: the oracle stands in where labels exist)
        missing = [n for n in spec.needs if n.startswith("dataset:")]
        if missing and not spec.fresh_process:
            rec = na_record(spec, missing, ctx)
            rec.environment = env = env or environment(ctx.threads)
            keep(rec)
        else:
            keep(table4_record(spec, runs, ctx))
    return [done[k] for k in the_plan.keys if k in done]


def _copy_for(record: CellRecord, spec: CellSpec) -> CellRecord:
    """``record`` (measured for one cell) under the key of ``spec``, an equal configuration."""
    from evsmap.runner.execute import spec_inputs

    data = record.as_dict()
    data.update(key=spec.key, table=spec.table, row=spec.row, label=spec.label,
                metrics=list(spec.metrics), inputs=spec_inputs(spec))
    # equal configurations measure the same quantities in the same order (the config key
    # lists them), so the values map by position
    data["values"] = {mine: record.values[theirs]
                      for mine, theirs in zip(spec.metrics, record.metrics, strict=True)
                      if theirs in record.values}
    if spec.key != record.key:
        data["notes"] = list(record.notes) + [f"same configuration as {record.key}"]
    return CellRecord.from_dict(data)


def write_run_file(ctx: RunContext, the_plan: Plan, path: Path, **fields: Any) -> None:
    import json

    data = {"tables": fields.pop("tables", list(TABLES)), "quick": ctx.quick,
            "data_root": ctx.data_root, "weights_dir": ctx.weights_dir,
            "available": sorted({r for s in the_plan.specs for r in s.requires}
                                - {n for s in the_plan.specs for n in s.needs}),
            "sequences": fields.pop("sequences", {}),
            "cells": the_plan.keys, "skipped": the_plan.skipped, "context": ctx.as_dict(),
            **fields}
    atomic_write_text(path, json.dumps(data, indent=1, default=str))
