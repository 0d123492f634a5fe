"""A whole ``evsmap reproduce`` run: plan, ``run.json``, the matrix of cells, the proxy
training, the int8 pass, ``run.json`` again.

:func:`reproduce` takes a :class:`Reproduction` (what the command line decided and checked:
the folder, the tables, the :class:`~evsmap.runner.runfile.RunSettings`, the user's systems, the
executor) and returns every record of the run; the report is built from the folder afterwards
(:mod:`evsmap.report`, a layer above). Cells already ``ok`` are kept with ``resume``.
"""

from __future__ import annotations

import shutil
import sys
from collections.abc import Iterable
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from evsmap.errors import EvsmapError
from evsmap.interrupt import set_resume_hint
from evsmap.runner.accounting import RunClock, process_age_s
from evsmap.runner.cell_base import environment
from evsmap.runner.context import RunContext
from evsmap.runner.estimate import Budget, Estimator, cell_duration, format_duration
from evsmap.runner.executors import CellExecutor
from evsmap.runner.mapping_dedup import same_runs
from evsmap.runner.mapping_labels import lacks_labels
from evsmap.runner.mapping_plan import missing_dataset, open_mapping_sequence
from evsmap.runner.matrix import Plan, plan, run_matrix
from evsmap.runner.records import CellRecord, RecordStore
from evsmap.runner.runfile import RUN_FILE, RunFile, RunSettings
from evsmap.runner.scannet import SCANNET, SCANNET_SEQUENCE_PREFIX, is_scannet_sequence
from evsmap.runner.systems import ExtraSystem, load_systems, systems_from_records
from evsmap.tables.schema import mapping_table, mapping_table_id


@dataclass
class Reproduction:
    """What a run does, decided and checked before anything is written.

    Args:
        out: the run folder.
        stamp: the run's name (a resumed run keeps its own).
        tables: the table ids to reproduce.
        settings: the run's settings (those ``run.json`` keeps).
        systems: the user's mapping systems (``--systems``, or the resumed run's).
        executor: where the cells run (not entered yet).
        resume: keep the records already ``ok``.
        force: with ``resume``, run every cell again.
        count_startup: count this process's age when the run begins as its start-up phase
            (the command line's run: the interpreter, the imports, the options' checks; not a
            run started inside a longer-lived process).
    """

    out: Path
    stamp: str
    tables: list[str]
    settings: RunSettings
    systems: list[ExtraSystem]
    executor: CellExecutor
    resume: bool = False
    force: bool = False
    count_startup: bool = False


def reproduce(job: Reproduction) -> list[CellRecord]:
    """Run ``job``: every cell of its plan not already done, then the proxy training
    (``settings.train``) and the int8 pass (``settings.precision``); ``run.json`` is written
    before the first cell and again at the end. Returns every record of the run.

    Raises:
        EvsmapError: ``settings.cells`` match no cell (a new folder is removed again).
    """
    clock = RunClock()
    if job.count_startup:
        clock.add("start-up", process_age_s() or 0.0)
    with clock.phase("plan"):
        ctx, the_plan, run = _planned(job)
    records = _measure(ctx, job, the_plan, run, clock)
    with clock.phase("extra passes"):
        records += _extra_passes(ctx, job, the_plan, run)
    with clock.phase("run.json"):
        run.finished = datetime.now(UTC).isoformat(timespec="seconds")
        run.time_accounting = clock.as_dict()
        run.write(job.out / RUN_FILE)
    return records


def _planned(job: Reproduction) -> tuple[RunContext, Plan, RunFile]:
    """The run's context and plan, and its ``run.json`` written as it starts.

    Raises:
        EvsmapError: ``settings.cells`` match no cell (a new folder is removed again).
    """
    s = job.settings
    created = not job.out.exists()
    job.out.mkdir(parents=True, exist_ok=True)
    ctx = RunContext.create(job.out, data_root=s.data_root, weights_dir=s.weights_dir,
                            quick=s.quick, strict_timing=s.strict_timing, extended=s.extended)
    ctx.scannet_scenes = tuple(s.scannet_scenes or ())
    ctx.scannet_step = s.scannet_step
    ctx.synthetic_labels = s.synthetic_labels
    if s.oracle_profile is not None:
        ctx.oracle_profile = s.oracle_profile
    ctx.use_device(s.device)
    the_plan = plan(ctx, job.tables, job.systems, cells=s.cells)
    if not the_plan.keys:
        if created:
            shutil.rmtree(job.out, ignore_errors=True)
        raise EvsmapError(f"--cells {','.join(s.cells or [])}: no cell of tables "
                          f"{', '.join(job.tables)} matches")
    if mapping_table_id() in job.tables and ctx.dataset_path("tum") is None:
        print(f"note: no real TUM sample under {ctx.data_root} (or datasets/): Table IV maps the "
              f"synthetic room only; `evsmap datasets fetch tum-fr1-xyz` adds the sample")
    run = run_file(ctx, job, the_plan)
    run.write(job.out / RUN_FILE)
    set_resume_hint(f"the finished cells are kept in {job.out}/records: resume with "
                    f"`evsmap reproduce --resume --out {job.out}`")
    return ctx, the_plan, run


def run_file(ctx: RunContext, job: Reproduction, the_plan: Plan) -> RunFile:
    """``run.json`` of ``job`` as it starts (``finished`` not yet set)."""
    labels = ("a trained proxy network's (--synthetic-labels network)"
              if ctx.synthetic_labels == "network" else
              f"ground truth (oracle segmenter, profile {ctx.oracle_profile})")
    sequences = {"synthetic": {**ctx.synthetic, "labels": labels}}
    scenes = sorted({r.sequence for r in the_plan.runs
                     if is_scannet_sequence(r.sequence) and r.sequence != SCANNET})
    for name in [*the_plan.sequences, *scenes]:
        if name != "synthetic":
            sequences[name] = describe_sequence(ctx, name)
    return RunFile(
        tables=job.tables, quick=ctx.quick, data_root=ctx.data_root,
        weights_dir=ctx.weights_dir,
        available=sorted({r for s in the_plan.specs for r in s.requires}
                         - {n for s in the_plan.specs for n in s.needs}),
        sequences=sequences, cells=the_plan.keys, skipped=the_plan.skipped,
        context=ctx.as_dict(), run=job.stamp,
        started=datetime.now(UTC).isoformat(timespec="seconds"), finished=None,
        settings=job.settings, environment=environment(ctx.threads),
        systems=[s.as_dict() for s in job.systems])


def _measure(ctx: RunContext, job: Reproduction, the_plan: Plan, run: RunFile,
             clock: RunClock) -> list[CellRecord]:
    """The matrix: the plan announced with its estimate, then every cell not done, on the
    job's executor, with a progress bar (or line per cell); its phases on ``clock``."""
    s = job.settings
    with clock.phase("estimate"):
        estimator = _estimator(ctx)
        pending = pending_cells(ctx, the_plan, resume=job.resume and not job.force)
        clock.estimate_s = estimator.run_s(pending)
        _announce(the_plan, pending, estimator, clock.estimate_s, s.budget)
    budget = Budget(s.budget) if s.budget else None
    watch = _Progress(len(the_plan.keys), pending, estimator)
    with job.executor as executor:
        if s.executor != "local":
            executor.prepare(ctx)
            print(executor.summary())
        records = run_matrix(ctx, the_plan, workers=s.workers, resume=job.resume,
                             force=job.force, on_record=watch.tick, executor=executor,
                             budget=budget, estimator=estimator, clock=clock)
        watch.close()
        run.executor = executor.describe()
    if watch.measured:  # what this run spent outside its cells: the next estimate's
        estimator.learn_outside(clock.as_dict()["wall_s"] - watch.spent, watch.measured)
    return records


def _extra_passes(ctx: RunContext, job: Reproduction, the_plan: Plan,
                  run: RunFile) -> list[CellRecord]:
    """``--train``'s proxy networks and ``--precision int8``'s records, noted in ``run``."""
    s = job.settings
    records: list[CellRecord] = []
    if s.train:
        from evsmap.runner.proxy import PROXY_MODELS, PROXY_RECIPE, run_proxy

        models = s.proxy_models or list(PROXY_MODELS)
        recipe = s.proxy_recipe or PROXY_RECIPE
        run.train = {"models": models, "recipe": recipe}
        records += run_proxy(ctx, models, recipe, tables=job.tables, resume=job.resume,
                             force=job.force)
    if s.precision == "int8":
        from evsmap.runner.int8 import run_int8

        run.precision = "int8"
        records += run_int8(ctx, the_plan.specs, resume=job.resume, force=job.force)
        if mapping_table_id() in job.tables:
            from evsmap.runner.realtime import run_realtime

            records += run_realtime(ctx, resume=job.resume, force=job.force)
    return records


def user_systems(path: Path | None, tables: list[str], resumed: RunFile | None,
                 source: Path) -> list[ExtraSystem]:
    """The user's mapping systems: those of TOML file ``path`` (``--systems``; their ids may
    not be the mapping table's own), or the ``resumed`` run's (``source``: its ``run.json``).

    Raises:
        EvsmapError: ``path`` is given without the mapping table, or is not a systems file.
    """
    from evsmap.runner.mapping_plan import REFERENCE_ROW, VARIANT_ROWS

    if resumed is not None:
        stored = resumed.systems
        return systems_from_records(stored, source=str(source)) if stored else []
    if path is None:
        return []
    if mapping_table_id() not in tables:
        raise EvsmapError("--systems: your systems are mapped with Table IV; add IV to --tables")
    taken = {r.id for r in mapping_table().rows} | {REFERENCE_ROW} | {
        row + suffix for row, (suffix, _, _) in VARIANT_ROWS.items()}
    return load_systems(path, taken=taken)


def describe_sequence(ctx: RunContext, name: str) -> dict[str, Any]:
    """What index.md says about a real mapping sequence: its folder, the frames mapped (all, or
    the ``--quick`` cap), their size, and whether it has labels for the oracle."""
    if is_scannet_sequence(name):
        path = ctx.dataset_path(SCANNET)
        info: dict[str, Any] = {"path": str(path), "scene": name.removeprefix(
            SCANNET_SEQUENCE_PREFIX), "step": ctx.scannet_step}
    else:
        path = ctx.dataset_path(name)
        info = {"path": str(path), "scene": path.name if path is not None else None}
    try:
        seq = open_mapping_sequence(ctx, name)
        n = len(seq) if ctx.frames is None else min(ctx.frames, len(seq))
        info["frames"] = n
        if n:
            first = seq.frame(0)
            image = first.depth if first.depth is not None else first.rgb
            if image is not None:
                info.update(width=int(image.shape[1]), height=int(image.shape[0]))
            info.update(
                        labels="ground truth (oracle segmenter)" if first.labels is not None
                        else "none (semantic systems need trained weights)")
    except EvsmapError as exc:
        info["labels"] = f"unreadable: {exc}"
    return info


def _estimator(ctx: RunContext) -> Estimator:
    """This machine's estimator (:mod:`evsmap.runner.estimate`), scaled by its calibration
    with the run's threads: the one taken now, or the best this machine has shown
    (:class:`~evsmap.measure.contention.CalibrationLog`) when that is higher, so a burst of
    other work at the start does not multiply the estimate (a load of 5.7 on 2 cores made one
    ten times too long); the running correction follows the machine as it is."""
    from evsmap.measure.contention import CalibrationLog, calibration_gmacs, machine_log_path
    from evsmap.models.module_utils import torch_threads

    with torch_threads(ctx.threads):
        gmacs = CalibrationLog(machine_path=machine_log_path()).best(calibration_gmacs())
    return Estimator.load(threads=ctx.threads, calibration_gmacs=gmacs, quick=ctx.quick)


def pending_cells(ctx: RunContext, the_plan: Plan, *, resume: bool) -> list[tuple[str, str]]:
    """``(key, kind)`` of the cells this run will measure (not those that need what is not
    here: weights, labels or a sequence's dataset, nor Table IV's, which are read from the
    mapping runs, nor, resuming, those done)."""
    store = RecordStore(ctx.out) if resume else None

    def done(key: str) -> bool:
        if store is None:
            return False
        record = store.get(key)
        return record is not None and record.status == "ok"

    items = [(s.key, s.kind) for s in the_plan.specs
             if not s.needs and s.kind != "mapping" and not done(s.key)]
    labels: dict[str, bool] = {}
    to_map, _ = same_runs(the_plan.runs)  # a run under two rows is mapped once
    items += [(r.key, "mapping") for r in to_map
              if not done(r.key) and missing_dataset(ctx, r.sequence) is None
              and not lacks_labels(ctx, r, labels)]
    return items


_SOURCE_WORDS = {"history": "earlier runs here",
                 "history (first run)": "this run's first pass here",
                 "history (first run, scaled)": "the first run here, less what it cached",
                 "reference": "the reference run scaled by this machine's calibration",
                 "default": "a default per kind of cell"}


def _announce(the_plan: Plan, pending: list[tuple[str, str]], estimator: Estimator,
              total_s: float, budget: float | None) -> None:
    """The plan in two lines: how many cells, what they need, and the estimated time."""
    from evsmap.environment import instruction_set

    sources = estimator.sources(pending)
    how = ", ".join(f"{n} from {_SOURCE_WORDS[k]}" for k, n in sorted(sources.items()))
    print(f"plan: {len(the_plan.keys)} cells, {len(pending)} to measure here; estimated "
          f"{format_duration(total_s)} on this machine ({instruction_set()}; {how})")
    if budget is not None:
        fits = "fits" if total_s <= budget * 60 else "does not fit: the cells that do not fit " \
                                                    "are recorded as not measured"
        print(f"--budget {budget:g} min: the estimate {fits} (the paper's claims first)")


class _Progress:
    """Cells done out of the plan's, and the time left: a bar on a terminal, else one line per
    measured cell on stderr."""

    def __init__(self, total: int, pending: Iterable[tuple[str, str]],
                 estimator: Estimator) -> None:
        from tqdm import tqdm

        self.estimator = estimator
        self.left = dict(pending)
        self.total = total
        self.count = 0
        self.terminal = sys.stderr.isatty()
        self.spent = 0.0  # the measured cells' durations (evsmap.runner.estimate.cell_duration)
        self.measured = 0
        self.bar = tqdm(total=total, desc="cells", unit="cell", leave=False,
                        disable=not self.terminal, file=sys.stderr)

    def tick(self, record: CellRecord) -> None:
        self.count += 1
        measured = self.left.pop(record.key, None) is not None
        duration = cell_duration(record)
        if measured and duration > 0:
            self.estimator.learn(record.key, record.kind, duration)
            self.spent += duration
            self.measured += 1
        eta = format_duration(self.estimator.remaining_s(self.left.items()))
        if self.terminal:
            self.bar.update(1)
            self.bar.set_postfix_str(f"~{eta} left", refresh=True)
        elif measured:
            print(f"[{self.count}/{self.total}] {record.status} {record.key} "
                  f"({duration:.0f} s); about {eta} left", file=sys.stderr, flush=True)

    def close(self) -> None:
        self.bar.close()
