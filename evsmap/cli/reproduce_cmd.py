"""``evsmap reproduce``: the main job. Expands the paper's Tables I-IV into cells, measures every
cell that can be measured on this machine (the rest say what they need), stores one record per
cell and writes the report folder: one Markdown and one CSV file per table with the paper's value
beside each measured one, an index and plots."""

from __future__ import annotations

import argparse
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING

from evsmap.cli.options import positive_float, positive_int
from evsmap.cli.outputs import Output, check_writable
from evsmap.errors import EvsmapError

if TYPE_CHECKING:
    from evsmap.runner.context import RunContext

TABLE_NAMES = {"I": "table1", "II": "table2", "III": "table3", "IV": "table4"}


def _tables(text: str) -> list[str]:
    out = []
    for part in text.split(","):
        name = part.strip().upper()
        if name not in TABLE_NAMES:
            raise argparse.ArgumentTypeError(
                f"unknown table {part.strip()!r} (choose from {', '.join(TABLE_NAMES)})")
        if TABLE_NAMES[name] not in out:
            out.append(TABLE_NAMES[name])
    return out


def _cells(text: str) -> list[str]:
    out = [g.strip() for g in text.split(",") if g.strip()]
    if not out:
        raise argparse.ArgumentTypeError("no cell pattern given")
    return list(dict.fromkeys(out))


def _models(text: str) -> list[str]:
    from evsmap.registry import SEGMENTERS

    out = [m.strip() for m in text.split(",") if m.strip()]
    for m in out:
        if m not in SEGMENTERS.names():
            raise argparse.ArgumentTypeError(f"unknown segmenter {m!r}")
    if not out:
        raise argparse.ArgumentTypeError("no model given")
    return list(dict.fromkeys(out))


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "reproduce", help="measure the paper's Tables I-IV and write a report folder",
        description="Measure every cell of the paper's Tables I-IV that this machine can "
                    "measure (parameters, FLOPs and CPU speed of every network; mapping rate "
                    "and map size of every system on the built-in synthetic sequence and the "
                    "real TUM sample; mIoU where prepared datasets and trained weights are "
                    "given) and write reports/<run>/ with the paper's value beside every "
                    "measured one. Cells that cannot be measured say what they need.")
    p.add_argument("--tables", type=_tables, default=None,
                   metavar="LIST", help="tables to reproduce, e.g. I,IV (default I,II,III,IV; "
                                        "with --resume, those of the run)")
    p.add_argument("--out", type=Path, metavar="DIR",
                   help="run folder (default reports/<UTC date-time>)")
    p.add_argument("--data-root", type=Path, metavar="DIR",
                   help="where prepared datasets (nyuv2/, sunrgbd/, cityscapes/) and mapping "
                        "sequences (tum_fr1_xyz/, rtabmap.bag, asl.bag, ours1.bag, ours2.bag) "
                        "are found (default $EVSMAP_DATA_ROOT or ../shared/data; datasets/ is "
                        "always searched too)")
    p.add_argument("--weights", "--weights-dir", dest="weights_dir", type=Path, metavar="DIR",
                   help="a folder of trained weights named <segmenter>@<dataset>.pt, e.g. "
                        "feagnet-v2@nyuv2.pt: the mIoU cells and the maps with a network's "
                        "classes need them (speed and complexity do not: they run each "
                        "network's random initialisation, seed 0, stated in the records)")
    p.add_argument("--quick", action=argparse.BooleanOptionalAction, default=None,
                   help="smoke test (under 3 minutes): 8 frames at 320x240, speed timed with "
                        "torch for a 3 s budget per cell (3 passes at least), speed cells above "
                        "1024x512 skipped (with --resume: as the run was made)")
    p.add_argument("--extended", action=argparse.BooleanOptionalAction, default=None,
                   help="also map Table IV's systems on the long synthetic sequence (640 "
                        "frames, 4 laps with revisits: the map growth and the Map Size "
                        "readings' check), at 5 cm beside 2 cm, and the C++ OctoMap on the "
                        "synthetic room: 33 more mapping runs, 16 of them of 640 frames (not "
                        "timed as a whole; with --resume: as the run was made)")
    p.add_argument("--budget", type=positive_float, default=None, metavar="MINUTES",
                   help="fit the run into this many minutes: a cell whose estimated time no "
                        "longer fits is not started and is recorded as not measured, with the "
                        "reason (the cells the paper's claims rest on run first); the estimate "
                        "is printed at the start")
    p.add_argument("--cells", type=_cells, default=None, metavar="GLOBS",
                   help="only the cells whose key matches one of these comma-separated globs, "
                        "e.g. 'table1/feagnet-*/complexity*' (keys as in records/*.json; a "
                        "Table IV cell brings its mapping runs); default: every cell of "
                        "--tables (with --resume: the run's)")
    p.add_argument("--workers", type=positive_int, default=None, metavar="N",
                   help="processes for the cells that are not timed (default 2; with --resume, "
                        "the run's); timed cells "
                        "always run alone, each in a fresh process (with --executor ray: not "
                        "used, each cell reserves the CPUs it uses)")
    p.add_argument("--executor", choices=("local", "ray"), default=None,
                   help="where the cells run: local (default, or the resumed run's: process "
                        "pools on this machine) "
                        "or ray (a Ray cluster, pip install \"evsmap[ray]\"): cells that are "
                        "not timed run as tasks on any node, each timed cell alone on a whole "
                        "node (docs/runner.md)")
    p.add_argument("--address", default=None, metavar="ADDR",
                   help="with --executor ray: the cluster to join (HOST:6379, or auto); "
                        "default: start a local Ray cluster with this machine's CPUs")
    p.add_argument("--strict-timing", action=argparse.BooleanOptionalAction, default=None,
                   help="refuse to time on a busy machine: stop at once when the load average "
                        "exceeds the cores, and record a speed cell whose calibration shows "
                        "contention (twice) as not measured instead of flagging it")
    p.add_argument("--systems", type=Path, default=None, metavar="FILE",
                   help="with Table IV: a TOML file of your own mapping systems (registered "
                        "updaters and segmenters, e.g. plug-ins) mapped beside the paper's on "
                        "the same sequences; see docs/plugins.md (with --resume: the run's)")
    p.add_argument("--resume", action="store_true",
                   help="continue the run in --out (after Ctrl-C, a failure or a crash): keep "
                        "its finished cells, run the rest, with the run's own settings (tables, "
                        "--quick, --cells, --systems, --train, --precision, data and weights "
                        "folders, executor, workers) unless given again")
    p.add_argument("--force", action="store_true",
                   help="with --resume: run every cell again")
    p.add_argument("--train", action=argparse.BooleanOptionalAction, default=None,
                   help="opt-in, long: train the missing proxy weights on evsmap's synthetic "
                        "rooms (synthrooms, prepared if missing) and report their mIoU and, "
                        "with Table IV, TFEAGMap's and EVSMap's maps made with the trained "
                        "network, in 'Synthetic proxy' sections (never in the paper's columns); "
                        "weights go to --weights DIR (default ~/.cache/evsmap/weights; with "
                        "--quick, the run's cache)")
    p.add_argument("--proxy-models", type=_models, default=None, metavar="LIST",
                   help="with --train: networks to train (default "
                        "feagnet-v1,feagnet-v2,fchardnet-70)")
    p.add_argument("--proxy-recipe", default=None, metavar="NAME",
                   help="with --train: training recipe (default synth-proxy)")
    p.add_argument("--precision", choices=("fp32", "int8"), default=None,
                   help="int8: also measure every network with a speed cell in int8 beside "
                        "fp32 (ONNX Runtime static QDQ, the scheme auto picks for this CPU: "
                        "speed-up, top-1 agreement, mIoU "
                        "where weights and data are here), in an 'int8 beside fp32' section of "
                        "Tables I-III and int8.csv; the paper's cells stay fp32 (default fp32; "
                        "with --resume, the run's)")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    import json

    from evsmap.interrupt import set_resume_hint
    from evsmap.report.build import build_report
    from evsmap.runner.context import RunContext
    from evsmap.runner.execute import environment
    from evsmap.runner.matrix import make_executor, plan, run_matrix, write_run_file

    stamp = datetime.now(UTC).strftime("%Y%m%d-%H%M%S")
    out = args.out or Path("reports") / stamp
    if args.force and not args.resume:
        raise EvsmapError("--force only applies with --resume (a new run measures everything)")
    if args.resume:
        if not (out / "run.json").is_file():
            raise EvsmapError(f"--resume: {out} holds no run (run.json missing)")
        try:
            previous = json.loads((out / "run.json").read_text())
            if not isinstance(previous, dict):
                raise ValueError("not a JSON object")
        except (OSError, ValueError) as exc:
            raise EvsmapError(f"--resume: {out / 'run.json'} is unreadable ({exc})") from None
        stamp = previous.get("run", stamp)
        _resume_settings(args, previous, out / "run.json")
        stored = list(previous.get("tables") or TABLE_NAMES.values())
        if args.tables is not None and args.tables != stored:
            raise EvsmapError(f"--resume: the run in {out} covers tables "
                              f"{', '.join(stored)}; resume it without --tables (or with the "
                              f"same list)")
        args.tables = stored
        stored_systems = previous.get("systems") or []
        if args.systems is not None:
            raise EvsmapError(f"--resume: a resumed run keeps its systems ({len(stored_systems)} "
                              f"stored in {out / 'run.json'}); resume it without --systems")
    elif out.exists() and any(out.iterdir()):
        raise EvsmapError(f"--out {out}: folder exists and is not empty (use --resume to "
                          f"continue a run there)")
    check_writable(Output("--out", out, folder=True, in_place=True))  # before minutes of work
    for name, value in SETTING_DEFAULTS.items():
        if getattr(args, name) is None:
            setattr(args, name, value)
    if args.tables is None:
        args.tables = list(TABLE_NAMES.values())
    if not args.train and (args.proxy_models is not None or args.proxy_recipe is not None):
        raise EvsmapError("--proxy-models and --proxy-recipe only apply with --train")
    if args.train and args.weights_dir is None:
        from evsmap.runner.proxy import default_weights_dir

        # a --quick run's 1-epoch weights stay in its own folder
        args.weights_dir = (out / "cache" / "weights" if args.quick else default_weights_dir())
        args.weights_dir.mkdir(parents=True, exist_ok=True)
    if args.weights_dir is not None and not args.weights_dir.is_dir():
        raise EvsmapError(f"--weights {args.weights_dir}: no such folder")
    # checked before anything is written: an unknown or missing executor is a usage error
    executor = make_executor(args.executor, address=args.address)
    systems = _systems(args, out)
    if args.data_root is not None and not args.data_root.is_dir():
        raise EvsmapError(f"--data-root {args.data_root}: no such folder")
    if args.strict_timing:
        import os

        load1 = os.getloadavg()[0]
        cores = os.cpu_count() or 1
        if load1 > cores:
            raise EvsmapError(f"--strict-timing: the machine is busy (load average {load1:.1f} "
                              f"on {cores} cores); wait until it is idle or drop "
                              f"--strict-timing (busy cells are then flagged)")
    created = not out.exists()
    out.mkdir(parents=True, exist_ok=True)

    ctx = RunContext.create(out, data_root=args.data_root, weights_dir=args.weights_dir,
                            quick=args.quick, strict_timing=args.strict_timing,
                            extended=args.extended)
    the_plan = plan(ctx, args.tables, systems, cells=args.cells)
    if not the_plan.keys:
        if created:
            import shutil

            shutil.rmtree(out, ignore_errors=True)
        raise EvsmapError(f"--cells {','.join(args.cells or [])}: no cell of tables "
                          f"{', '.join(args.tables)} matches")
    if "table4" in args.tables and ctx.dataset_path("tum") is None:
        print(f"note: no real TUM sample under {ctx.data_root} (or datasets/): Table IV maps the "
              f"synthetic room only; `evsmap datasets fetch tum-fr1-xyz` adds the sample")
    started = datetime.now(UTC).isoformat(timespec="seconds")
    env = environment(ctx.threads)
    sequences = {"synthetic": {**ctx.synthetic, "labels": "ground truth (oracle segmenter)"}}
    for name in the_plan.sequences:
        if name != "synthetic":
            sequences[name] = _describe_sequence(ctx, name)
    fields = dict(run=stamp, started=started, finished=None, tables=args.tables,
                  settings=settings_record(args),
                  environment=env, sequences=sequences,
                  systems=[s.as_dict() for s in systems])
    write_run_file(ctx, the_plan, out / "run.json", **fields)
    set_resume_hint(f"the finished cells are kept in {out}/records: resume with "
                    f"`evsmap reproduce --resume --out {out}`")

    from evsmap.runner.estimate import Budget

    estimator = _estimator(ctx, args)
    pending = _pending(ctx, the_plan, out, resume=args.resume and not args.force)
    total_s = estimator.total_s(pending)
    _announce(the_plan, pending, estimator, total_s, args.budget)
    budget = Budget(args.budget) if args.budget else None
    watch = _Progress(len(the_plan.keys), pending, estimator)

    with executor:
        if args.executor != "local":
            executor.prepare(ctx)
            print(executor.summary())
        records = run_matrix(ctx, the_plan, workers=args.workers, resume=args.resume,
                             force=args.force, on_record=watch.tick, executor=executor,
                             budget=budget, estimator=estimator)
        watch.close()
        fields["executor"] = executor.describe()
    if args.train:
        from evsmap.runner.proxy import PROXY_MODELS, PROXY_RECIPE, run_proxy

        models = args.proxy_models or list(PROXY_MODELS)
        recipe = args.proxy_recipe or PROXY_RECIPE
        fields["train"] = {"models": models, "recipe": recipe}
        records += run_proxy(ctx, models, recipe, tables=args.tables, resume=args.resume,
                             force=args.force)
    if args.precision == "int8":
        from evsmap.runner.int8 import run_int8

        fields["precision"] = "int8"
        records += run_int8(ctx, the_plan.specs, resume=args.resume, force=args.force)
    fields["finished"] = datetime.now(UTC).isoformat(timespec="seconds")
    write_run_file(ctx, the_plan, out / "run.json", **fields)
    written = build_report(out)
    ok = sum(r.status == "ok" for r in records)
    na = sum(r.status == "na" for r in records)
    err = [r for r in records if r.status == "error"]
    print(f"{len(records)} cells: {ok} measured, {na} n/a (need data, weights or a Jetson), "
          f"{len(err)} failed")
    for r in err[:10]:
        print(f"  failed: {r.key}: {r.error}")
    print(f"report written to {out}/ ({', '.join(p.name for p in written[:6])}, ...)")
    return 1 if err else 0


def _estimator(ctx: RunContext, args: argparse.Namespace):
    """This machine's estimator (:mod:`evsmap.runner.estimate`), scaled by a calibration
    taken now with the run's threads."""
    import torch

    from evsmap.measure.contention import calibration_gmacs
    from evsmap.runner.estimate import Estimator

    previous = torch.get_num_threads()
    try:
        torch.set_num_threads(ctx.threads)
        gmacs = calibration_gmacs()
    finally:
        torch.set_num_threads(previous)
    return Estimator.load(threads=ctx.threads, calibration_gmacs=gmacs, quick=ctx.quick)


def _pending(ctx: RunContext, the_plan, out: Path, *,
             resume: bool) -> list[tuple[str, str]]:
    """``(key, kind)`` of the cells this run will measure (not those that need what is not
    here, nor Table IV's, which are read from the mapping runs, nor, resuming, those done)."""
    from evsmap.runner.matrix import lacks_labels
    from evsmap.runner.records import RecordStore

    store = RecordStore(out) if resume else None

    def done(key: str) -> bool:
        if store is None:
            return False
        record = store.get(key)
        return record is not None and record.status == "ok"

    items = [(s.key, s.kind) for s in the_plan.specs
             if not s.needs and s.kind != "mapping" and not done(s.key)]
    labels: dict[str, bool] = {}
    items += [(r.key, "mapping") for r in the_plan.runs
              if not done(r.key) and not lacks_labels(ctx, r, labels)]
    return items


def _announce(the_plan, pending, estimator, total_s: float, budget: float | None) -> None:
    """The plan in two lines: how many cells, what they need, and the estimated time."""
    from evsmap.environment import instruction_set
    from evsmap.runner.estimate import format_duration

    sources = estimator.sources(pending)
    how = ", ".join(f"{n} from {_SOURCE_WORDS[k]}" for k, n in sorted(sources.items()))
    print(f"plan: {len(the_plan.keys)} cells, {len(pending)} to measure here; estimated "
          f"{format_duration(total_s)} on this machine ({instruction_set()}; {how})")
    if budget is not None:
        fits = "fits" if total_s <= budget * 60 else "does not fit: the cells that do not fit " \
                                                    "are recorded as not measured"
        print(f"--budget {budget:g} min: the estimate {fits} (the paper's claims first)")


_SOURCE_WORDS = {"history": "earlier runs here", "reference": "the reference run scaled by "
                 "this machine's calibration", "default": "a default per kind of cell"}


class _Progress:
    """Cells done out of the plan's, and the time left: a bar on a terminal, else one line per
    measured cell on stderr."""

    def __init__(self, total: int, pending: list[tuple[str, str]], estimator) -> None:
        import sys

        from tqdm import tqdm

        self.estimator = estimator
        self.left = dict(pending)
        self.total = total
        self.count = 0
        self.terminal = sys.stderr.isatty()
        self.bar = tqdm(total=total, desc="cells", unit="cell", leave=False,
                        disable=not self.terminal, file=sys.stderr)

    def tick(self, record) -> None:
        import sys

        from evsmap.runner.estimate import format_duration

        self.count += 1
        measured = self.left.pop(record.key, None) is not None
        if measured and record.seconds > 0:
            self.estimator.learn(record.key, record.kind, record.seconds)
        eta = format_duration(self.estimator.remaining_s(self.left.items()))
        if self.terminal:
            self.bar.update(1)
            self.bar.set_postfix_str(f"~{eta} left", refresh=True)
        elif measured:
            print(f"[{self.count}/{self.total}] {record.status} {record.key} "
                  f"({record.seconds:.0f} s); about {eta} left", file=sys.stderr, flush=True)

    def close(self) -> None:
        self.bar.close()


SETTING_DEFAULTS: dict[str, object] = {
    "quick": False, "cells": None, "workers": 2, "executor": "local", "address": None,
    "strict_timing": False, "train": False, "proxy_models": None, "proxy_recipe": None,
    "precision": "fp32", "data_root": None, "weights_dir": None, "budget": None,
    "extended": False}
"""``reproduce``'s settings that ``run.json`` keeps (``settings``) and ``--resume`` takes back
when they are not given again, with their defaults for a new run."""

FIXED_SETTINGS = ("quick", "cells", "train", "proxy_models", "proxy_recipe", "precision",
                  "extended")
"""Settings that decide what a run measures: a resumed run may not change them (its records
would be a mix); the others (where the data is, how many workers) may change."""

_PATH_SETTINGS = ("data_root", "weights_dir")


def settings_record(args: argparse.Namespace) -> dict[str, object]:
    """The settings of this run, as ``run.json`` stores them."""
    return {name: (str(value) if name in _PATH_SETTINGS and value is not None else value)
            for name in SETTING_DEFAULTS for value in [getattr(args, name)]}


def _flag(name: str) -> str:
    return "--" + name.replace("_", "-")


def _resume_settings(args: argparse.Namespace, previous: dict, source: Path) -> None:
    """Fill the settings not given with the resumed run's (``run.json``); refuse a given one
    that would change what the run measures. Runs written before ``settings`` was stored keep
    at least their ``quick``."""
    stored = previous.get("settings")
    if not isinstance(stored, dict):
        stored = {"quick": bool(previous.get("quick"))}
    for name in SETTING_DEFAULTS:
        given = getattr(args, name)
        if name not in stored:
            continue
        value = stored[name]
        if name in _PATH_SETTINGS and value is not None:
            value = Path(value)
        if given is None:
            setattr(args, name, value)
        elif name in FIXED_SETTINGS and given != value:
            if isinstance(value, bool):
                made = f"{'with' if value else 'without'} {_flag(name)}"
            else:
                made = f"with {_flag(name)} {value if value is not None else '(not given)'}"
            raise EvsmapError(f"--resume: the run in {source.parent} was made {made}; resume "
                              f"it without {_flag(name)} (a resumed run keeps what it "
                              f"measures)")


def _systems(args: argparse.Namespace, out: Path) -> list:
    """The user's mapping systems: ``--systems FILE``, or a resumed run's (its ``run.json``)."""
    from evsmap.runner.mapping_cells import REFERENCE_ROW, VARIANT_ROWS
    from evsmap.runner.systems import load_systems, systems_from_records
    from evsmap.tables.schema import load_tables

    taken = {r.id for r in load_tables()["table4"].rows} | {REFERENCE_ROW} | {
        row + suffix for row, (suffix, _, _) in VARIANT_ROWS.items()}
    if args.resume:
        import json

        stored = json.loads((out / "run.json").read_text()).get("systems") or []
        return systems_from_records(stored, source=str(out / "run.json")) if stored else []
    if args.systems is None:
        return []
    if "table4" not in args.tables:
        raise EvsmapError("--systems: your systems are mapped with Table IV; add IV to --tables")
    return load_systems(args.systems, taken=taken)


def _describe_sequence(ctx: RunContext, name: str) -> dict:
    """What index.md says about a real mapping sequence: its folder, the frames mapped (all, or
    the ``--quick`` cap), their size, and whether it has labels for the oracle."""
    from evsmap.runner.execute import open_mapping_sequence

    path = ctx.dataset_path(name)
    info: dict = {"path": str(path), "scene": path.name if path is not None else None}
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
