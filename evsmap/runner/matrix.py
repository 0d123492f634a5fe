"""Scheduling a run: expand the tables into cells, decide what can be measured here, run the
cells and store each record as it finishes.

Order and isolation:

1. Cells that cannot be measured here (``needs``) are recorded as ``na`` at once.
2. The cells the paper's claims rest on (:func:`evsmap.tables.claims.claims_first`: the rows
   the claims name, the baselines, FEAGNet's rows, Tables III and IV) are measured before the
   compared networks, each group as follows.
3. Complexity and accuracy cells run in a process pool (``workers``); cells with the same
   configuration (``CellSpec.config_key``: e.g. FEAGNet-V2's parameters in Tables I and III) are
   measured once and recorded under each key.
4. Timing cells (speed, and the mapping runs behind Table IV) then run one at a time per timing
   slot, each in a fresh interpreter (``spawn``, one task per process), so no cell inherits
   another's warm caches, threads or memory, and nothing else of the run competes for the cores.
5. Table IV's cells are read from the mapping runs.

With a ``--budget``, a cell whose estimate (:mod:`evsmap.runner.estimate`) does not fit in the
time left is recorded as not measured, with the reason, instead of being started.

Where the cells run is the executor's (:mod:`evsmap.runner.executors`): this machine by default
(one timing slot), or a Ray cluster (:mod:`evsmap.runner.ray_executor`: one timing slot per
timing node, each timed cell holding its whole node). The records are written here, by the
driver, as the cells finish.

With ``resume`` the records already ``ok`` are kept and everything else is run again; ``force``
reruns everything.
"""

from __future__ import annotations

import queue
import time
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import (
    Executor,
    Future,
    ThreadPoolExecutor,
    as_completed,
)
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from evsmap.errors import EvsmapError
from evsmap.runner.accounting import (
    RunClock,
    phase,
    pooled_around,
    settle_around,
    stamp,
    worker_stamps,
)
from evsmap.runner.cell_base import environment, na_record
from evsmap.runner.context import RunContext
from evsmap.runner.estimate import Budget, Estimator
from evsmap.runner.execute import execute_mapping, execute_spec
from evsmap.runner.executors import (
    EXECUTORS,
    CellExecutor,
    LocalExecutor,
    TimingSlot,
    fresh_process,
    spawn_pool,
)
from evsmap.runner.mapping_dedup import copied_record, same_runs
from evsmap.runner.mapping_labels import lacks_labels, unlabelled_record
from evsmap.runner.mapping_plan import MappingRun, mapping_runs, with_synthetic_labels
from evsmap.runner.records import CellRecord, RecordStore
from evsmap.runner.systems import ExtraSystem
from evsmap.runner.table4_reading import table4_record
from evsmap.tables.schema import CellSpec, expand, load_tables, mapping_table_id

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


def plan(ctx: RunContext, tables: Iterable[str] | None = None,
         systems: Sequence[ExtraSystem] = (), *, cells: Sequence[str] | None = None) -> Plan:
    """Expand ``tables`` (default: all) against what is available here; with the mapping table
    (Table IV), the user's ``systems`` (``--systems``) map the same sequences as its rows.
    ``cells``: keep only the cells whose key matches one of these globs (``fnmatch``), and the
    mapping runs that a kept Table IV cell is read from or that match themselves."""
    loaded = load_tables()
    tables = list(loaded) if tables is None else list(tables)
    specs: list[CellSpec] = []
    for tid in tables:
        first = expand(loaded[tid])
        requires = sorted({r for s in first for r in s.requires})
        specs += expand(loaded[tid], available=ctx.available(requires))
    skipped = []
    if ctx.quick:
        from evsmap.tables.claims import claims_first

        keep = []
        for s in specs:
            if s.needs:
                keep.append(s)
            elif claims_first(s.table, s.row):
                skipped.append((s.key, "skipped by --quick (a compared network; the full run "
                                       "measures it)"))
            elif s.kind == "speed" and s.input_size and \
                    s.input_size[0] * s.input_size[1] > QUICK_MAX_PIXELS:
                skipped.append((s.key, "skipped by --quick (input above 1024x512)"))
            else:
                keep.append(s)
        specs = keep
    sequences = []
    if mapping_table_id(loaded) in tables:
        sequences = ["synthetic"] + (["synthetic-long"] if ctx.synthetic_long else []) + [
            d for d in ("tum", "rtabmap", "asl", "ours1", "ours2")
            if ctx.dataset_path(d) is not None]
    runs = mapping_runs(sequences, ctx.resolutions(), systems,
                        reference_on_synthetic=ctx.reference_on_synthetic) if sequences else []
    if sequences:  # the semantic-detail section: Table IV's updates, one network, 3D scores
        from evsmap.runner.detail import detail_runs

        runs += detail_runs(ctx)
    runs = with_synthetic_labels(ctx, runs)  # --synthetic-labels network
    if cells is not None:
        from fnmatch import fnmatchcase

        def wanted(key: str) -> bool:
            return any(fnmatchcase(key, glob) for glob in cells)

        specs = [s for s in specs if wanted(s.key)]
        rows = {s.row for s in specs if s.kind == "mapping"}
        runs = [r for r in runs if r.row in rows or wanted(r.key)]
        skipped = [(k, why) for k, why in skipped if wanted(k)]
    return Plan(specs, runs, sequences, skipped)


# ------------------------------------------------------------------ workers (top level: picklable)
def _spec_worker(table: str, key: str, ctx_data: dict[str, Any]) -> dict[str, Any]:
    entered = stamp()
    ctx = RunContext(**ctx_data)
    spec = next(s for s in expand(load_tables()[table]) if s.key == key)
    record = execute_spec(spec, ctx)
    record.around = worker_stamps(entered, record.around.get("began", entered))
    return record.as_dict()


def _mapping_worker(run: MappingRun, ctx_data: dict[str, Any]) -> dict[str, Any]:
    entered = stamp()
    record = execute_mapping(run, RunContext(**ctx_data))
    record.around = worker_stamps(entered, record.around.get("began", entered))
    return record.as_dict()


_fresh_executor = fresh_process
"""One task per fresh interpreter, one at a time (a module name, so tests can replace it)."""


def _spawn_pool(workers: int) -> Executor:
    """The local pool (a module name, so tests can replace it)."""
    return spawn_pool(workers)


def make_executor(name: str, *, address: str | None = None) -> CellExecutor:
    """The executor called ``name`` (:data:`evsmap.runner.executors.EXECUTORS`); ``address``
    is the Ray cluster to join (Ray only). Ray is imported only here, when it is chosen."""
    if name not in EXECUTORS:
        raise EvsmapError(f"unknown executor {name!r} (choose from {', '.join(EXECUTORS)})")
    if name == "local":
        if address is not None:
            raise EvsmapError("--address only applies with --executor ray")
        return LocalExecutor(pool=lambda n: _spawn_pool(n), fresh=lambda: _fresh_executor())
    from evsmap.runner.ray_executor import RayExecutor

    return RayExecutor(address=address)


def _result(fut: Future[dict[str, Any]], key: str, out: str | Path) -> dict[str, Any]:
    """A cell's record from its worker; a worker that died (killed from outside, out of
    memory) stops the run with one line: the finished cells are kept for ``--resume``."""
    from concurrent.futures.process import BrokenProcessPool

    try:
        return fut.result()
    except BrokenProcessPool:
        raise EvsmapError(f"a worker process died while measuring {key} (killed from "
                          f"outside, or out of memory); the finished cells are kept: resume "
                          f"with `evsmap reproduce --resume --out {out}`") from None


def _severity(record: CellRecord) -> float | None:
    from evsmap.measure.contention import severity

    machine = record.details.get("contention") if record.status == "ok" else None
    return None if not machine else severity(machine)


def _timed_mapping(run: MappingRun, ctx: RunContext,
                   fresh: Callable[[], Executor]) -> CellRecord:
    """A mapping run in a fresh process. One that the calibration says ran on a busy machine is
    run once more after a pause (as a contended speed cell is) when other processes used the
    cores (:func:`evsmap.measure.contention.retry_can_help`), and the less contended of the
    two kept; with ``--strict-timing`` one still contended is recorded as not measured."""
    from evsmap.runner.cell_base import RETRY_PAUSE_S, STRICT_PAUSE_S

    first_submitted = stamp()

    def once() -> CellRecord:
        submitted = stamp()
        with fresh() as ex:
            rec = CellRecord.from_dict(
                _result(ex.submit(_mapping_worker, run, ctx.as_dict()), run.key, ctx.out))
        rec.around = settle_around(rec.around, rec.seconds, submitted, stamp(), first_submitted)
        return rec

    from evsmap.measure.contention import HOST_SLOWDOWN_NOTE, describe, retry_can_help

    record = once()
    first = _severity(record)
    if first is None or not record.details["contention"]["contended"]:
        return record
    if not ctx.strict_timing and not retry_can_help(record.details["contention"]):
        record.notes.append(HOST_SLOWDOWN_NOTE)
        return record
    why = describe(record.details["contention"])
    time.sleep(STRICT_PAUSE_S if ctx.strict_timing else RETRY_PAUSE_S)
    again = once()
    if (_severity(again) or float("inf")) < first:
        record = again
    else:  # the kept first try: the second and its pause are its retry
        record.around["retry_s"] = round(again.around["wall_s"] - record.around["wall_s"], 4)
        record.around["wall_s"] = again.around["wall_s"]
    machine = record.details["contention"]
    if ctx.strict_timing and machine["contended"]:
        return CellRecord(
            key=record.key, table=record.table, row=record.row, label=record.label,
            kind=record.kind, metrics=list(record.metrics), status="na",
            needs=["an idle machine"], inputs=dict(record.inputs), details=dict(record.details),
            reason=f"n/a - --strict-timing: the machine was busy in both tries "
                   f"({describe(machine)}); rerun when it is idle",
            environment=record.environment, around=record.around)
    record.notes.append(f"timed twice: the first try was {why}; kept the less contended")
    return record


def _run_timed(items: list[Any], run_one: Callable[[Any, TimingSlot], CellRecord],
               slots: list[TimingSlot], keep: Callable[[CellRecord], None]) -> None:
    """``run_one(item, slot)`` for every item, one at a time per slot; each record kept (by
    this thread) as it finishes. One slot: in order, in this thread."""
    if not items:
        return
    if len(slots) == 1:
        for item in items:
            keep(run_one(item, slots[0]))
        return
    free: queue.Queue[TimingSlot] = queue.Queue()
    for slot in slots:
        free.put(slot)

    def task(item: Any) -> CellRecord:
        slot = free.get()
        try:
            return run_one(item, slot)
        finally:
            free.put(slot)

    with ThreadPoolExecutor(max_workers=len(slots)) as threads:
        for fut in as_completed([threads.submit(task, item) for item in items]):
            keep(fut.result())


def _slot_context(ctx: RunContext, slot: TimingSlot) -> RunContext:
    """The context of a timed cell in ``slot``: it uses all the slot's CPUs as threads."""
    if slot.cpus is None or slot.cpus == ctx.threads:
        return ctx
    return replace(ctx, threads=slot.cpus)


def _placed(record: CellRecord, executor: CellExecutor) -> CellRecord:
    record.environment.setdefault("executor", executor.placement())
    return record


def run_matrix(ctx: RunContext, the_plan: Plan, *, workers: int = 1, resume: bool = False,
               force: bool = False,
               on_record: Callable[[CellRecord], None] | None = None,
               pool: Callable[[int], Executor] | None = None,
               fresh: Callable[[], Executor] | None = None,
               executor: CellExecutor | None = None, budget: Budget | None = None,
               estimator: Estimator | None = None,
               clock: RunClock | None = None) -> list[CellRecord]:
    """Run every cell of ``the_plan`` not already done; returns all records of the plan.

    ``executor`` runs the cells (an entered :class:`~evsmap.runner.executors.CellExecutor`;
    default: :class:`~evsmap.runner.executors.LocalExecutor` on this machine, whose pools
    ``pool(workers)`` and ``fresh()`` make: spawned process pools unless given; tests pass
    in-process ones). ``resume`` and ``force`` are decided here, before anything is scheduled,
    whichever the executor.

    The cells the paper's claims rest on run first (:func:`evsmap.tables.claims.claims_first`).
    With a ``budget``, a cell whose ``estimator`` estimate does not fit in the time left is not
    started: it is recorded as not measured, with the reason. ``clock``: the run's phases are
    added to it (:mod:`evsmap.runner.accounting`)."""
    if executor is None:
        executor = LocalExecutor(pool=pool or _spawn_pool, fresh=fresh or _fresh_executor)
    elif pool is not None or fresh is not None:
        raise ValueError("give pool/fresh or an executor, not both")
    store = RecordStore(ctx.out)
    done = _kept(store, the_plan) if resume and not force else {}

    def keep(record: CellRecord) -> None:
        store.write(record)
        done[record.key] = record
        if on_record is not None:
            on_record(record)

    env = _Environment(ctx.threads)
    with phase(clock, "n/a cells"):
        todo = _record_needs(ctx, the_plan.specs, done, keep, env)
    runs_left = [r for r in the_plan.runs if r.key not in done]
    with phase(clock, "executor"):
        if todo or runs_left:
            executor.prepare(ctx)
        slots = executor.timing_slots() if any(s.fresh_process for s in todo) or runs_left \
            else []
    left_out = _budget_rule(budget, estimator)

    from evsmap.tables.claims import claims_first

    # the cells the paper's claims rest on first (evsmap.tables.claims), then the others: a run
    # stopped early has answered the claims
    for first in (0, 1):
        group = [s for s in todo if claims_first(s.table, s.row) == first]
        group_runs = runs_left if first == 0 else []
        _run_group(ctx, group, group_runs, done, keep, executor, workers, slots, left_out,
                   clock)
    with phase(clock, "Table IV read"):
        _read_mapping_cells(ctx, the_plan, done, keep, env)
    return [done[k] for k in the_plan.keys if k in done]


class _Environment:
    """The machine's environment, taken once, when a record first needs it."""

    def __init__(self, threads: int) -> None:
        self.threads = threads
        self.taken: dict[str, Any] | None = None

    def __call__(self) -> dict[str, Any]:
        if self.taken is None:
            self.taken = environment(self.threads)
        return self.taken


def _kept(store: RecordStore, the_plan: Plan) -> dict[str, CellRecord]:
    """The plan's records already ``ok`` in ``store`` (a resumed run keeps them)."""
    done: dict[str, CellRecord] = {}
    for key in the_plan.keys:
        rec = store.get(key)
        if rec is not None and rec.status == "ok":
            done[key] = rec
    return done


def _record_needs(ctx: RunContext, specs: list[CellSpec], done: dict[str, CellRecord],
                  keep: Callable[[CellRecord], None],
                  env: Callable[[], dict[str, Any]]) -> list[CellSpec]:
    """Record the cells that cannot run here (``needs``) as ``na``; returns those to measure
    (not the mapping cells, read from the mapping runs, nor those done)."""
    todo: list[CellSpec] = []
    for spec in specs:
        if spec.key in done or spec.kind == "mapping":
            continue
        if spec.needs:
            rec = na_record(spec, list(spec.needs), ctx)
            rec.environment = env()
            keep(rec)
        else:
            todo.append(spec)
    return todo


def _budget_rule(budget: Budget | None,
                 estimator: Estimator | None) -> Callable[[str, str], str | None]:
    """``left_out(key, kind)``: why ``budget`` leaves a cell out, or None."""

    def left_out(key: str, kind: str) -> str | None:
        if budget is None:
            return None
        return budget.refuses(estimator.seconds(key, kind)[0] if estimator else 0.0)

    return left_out


def _read_mapping_cells(ctx: RunContext, the_plan: Plan, done: dict[str, CellRecord],
                        keep: Callable[[CellRecord], None],
                        env: Callable[[], dict[str, Any]]) -> None:
    """The mapping table's cells, read from the mapping runs."""
    runs = {r.key: done[r.key] for r in the_plan.runs if r.key in done}
    for spec in the_plan.specs:
        if spec.kind != "mapping" or spec.key in done:
            continue
        # a map size needs its sequence; the rate is measured on whichever sequence the system
        # could map (weights are resolved by the runs: the oracle stands in where labels exist)
        missing = [n for n in spec.needs if n.startswith("dataset:")]
        if missing and not spec.fresh_process:
            rec = na_record(spec, missing, ctx)
            rec.environment = env()
            keep(rec)
        else:
            keep(table4_record(spec, runs, ctx))


def _skip_record(spec: CellSpec | MappingRun, why: str, ctx: RunContext) -> CellRecord:
    """A cell --budget left out: not measured, with the reason."""
    if isinstance(spec, MappingRun):
        base = spec.base_fields()
    else:
        from evsmap.runner.cell_base import spec_inputs

        base = {"key": spec.key, "table": spec.table, "row": spec.row, "label": spec.label,
                "kind": spec.kind, "metrics": list(spec.metrics), "inputs": spec_inputs(spec)}
    record = CellRecord(**base, status="na", needs=["time"], reason=why)
    record.environment = environment(ctx.threads)
    return record


def _run_group(ctx: RunContext, specs: list[CellSpec], runs: list[MappingRun],
               done: dict[str, CellRecord], keep: Callable[[CellRecord], None],
               executor: CellExecutor, workers: int, slots: list[TimingSlot],
               left_out: Callable[[str, str], str | None],
               clock: RunClock | None = None) -> None:
    """Complexity and accuracy in a pool (once per configuration), then the timed cells one at a
    time per timing slot, each in a fresh process, then the mapping runs."""
    with phase(clock, "untimed cells"):
        _run_pooled(ctx, [s for s in specs if not s.fresh_process], keep, executor, workers,
                    left_out)
    timed = [s for s in specs if s.fresh_process]

    def time_spec(spec: CellSpec, slot: TimingSlot) -> CellRecord:
        why = left_out(spec.key, spec.kind)
        if why:
            return _skip_record(spec, why, ctx)
        submitted = stamp()
        with executor.fresh(slot) as ex:
            data = _slot_context(ctx, slot).as_dict()
            record = CellRecord.from_dict(
                _result(ex.submit(_spec_worker, spec.table, spec.key, data), spec.key,
                        ctx.out))
        record.around = settle_around(record.around, record.seconds, submitted, stamp())
        return _placed(record, executor)

    def time_run(run: MappingRun, slot: TimingSlot) -> CellRecord:
        why = left_out(run.key, "mapping")
        if why:
            return _skip_record(run, why, ctx)
        return _placed(_timed_mapping(run, _slot_context(ctx, slot),
                                      lambda: executor.fresh(slot)), executor)

    with phase(clock, "timed cells"):
        _run_timed(timed, time_spec, slots, keep)
    labels_cache: dict[str, bool] = {}
    to_map: list[MappingRun] = []
    with phase(clock, "labels check"):
        for run in runs:
            if run.segmenter is not None and lacks_labels(ctx, run, labels_cache):
                rec = unlabelled_record(run)
                rec.environment = environment(ctx.threads)
                keep(rec)
                continue
            to_map.append(run)
    to_map, copies = same_runs(to_map)
    firsts = {r.key: r for r in to_map}

    def keep_with_copies(record: CellRecord) -> None:
        keep(record)
        for run in copies.get(record.key, []):
            keep(copied_record(record, firsts[record.key], run, ctx.out))

    with phase(clock, "mapping runs"):
        _run_timed(to_map, time_run, slots, keep_with_copies)


def _run_pooled(ctx: RunContext, pooled: list[CellSpec], keep: Callable[[CellRecord], None],
                executor: CellExecutor, workers: int,
                left_out: Callable[[str, str], str | None]) -> None:
    """The cells that are not timed, in the executor's pool: each configuration once, its
    record copied under every key that shares it."""
    by_config: dict[str, list[CellSpec]] = {}
    for spec in pooled:
        why = left_out(spec.key, spec.kind)
        if why:
            keep(_skip_record(spec, why, ctx))
        else:
            by_config.setdefault(spec.config_key, []).append(spec)
    if not by_config:
        return
    threads = executor.pool_threads(ctx.threads)
    data = (ctx if threads == ctx.threads else replace(ctx, threads=threads)).as_dict()
    with executor.pool(workers, threads) as ex:
        futures: dict[Future[dict[str, Any]], list[CellSpec]] = {
            ex.submit(_spec_worker, group[0].table, group[0].key, data): group
            for group in by_config.values()}
        for fut in as_completed(futures):
            group = futures[fut]
            first = _placed(CellRecord.from_dict(_result(fut, group[0].key, ctx.out)), executor)
            # an untimed cell's share of its pool's time; the copies cost nothing more
            first.around = pooled_around(first.seconds, workers)
            for i, spec in enumerate(group):
                copy = _copy_for(first, spec)
                if i:
                    copy.around = pooled_around(0.0, workers)
                keep(copy)


def _copy_for(record: CellRecord, spec: CellSpec) -> CellRecord:
    """``record`` (measured for one cell) under the key of ``spec``, an equal configuration."""
    from evsmap.runner.cell_base import spec_inputs

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
