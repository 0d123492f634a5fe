"""``evsmap explore``: where the paper's mapping claims hold - a multi-objective Optuna study over
a map updater's options and the shared front-end settings (docs/explore.md).

This module parses and checks the options (one line and exit 2 for a bad one, before a trial
runs and without touching a stored study); the study is :mod:`evsmap.explore`'s, its report
:mod:`evsmap.report.explore`'s."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

from evsmap.cli.options import key_value, nonnegative_int
from evsmap.errors import EvsmapError

DEFAULT_TRIALS = 40


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "explore", help="search a map updater's design space (Optuna, multi-objective)",
        description="Explore a map updater's options and the shared front-end settings "
                    "(resolution, max and ray-casting range) with a seeded multi-objective "
                    "Optuna study: every trial maps the sequence, measures the map's size "
                    "(Table IV's reading), its 3D accuracy and mIoU against ground truth and "
                    "its update rate as a ratio to OctoMap C++ timed in the same process, "
                    "beside the baseline's map at the same settings. Writes OUT/index.md (the "
                    "answer: where the map is smaller than the baseline's at no more than 1 "
                    "point of 3D mIoU lost), the Pareto fronts as plots and OUT/trials.csv. "
                    "The study lives in OUT/study.db (or --storage): --resume continues it "
                    "after an interruption, and several processes or machines may share it.")
    what = p.add_argument_group("what is explored")
    what.add_argument("--updater", default="multiclass-bayes", metavar="NAME",
                      help="the updater whose shipped space is explored (default "
                           "multiclass-bayes, EVSMaP's map; evsmap/explore/spaces/)")
    what.add_argument("--space", type=Path, default=None, metavar="FILE",
                      help="a search space TOML file instead of the shipped one (parameters, "
                           "ranges, defaults, baseline, sampler, objectives; docs/explore.md)")
    what.add_argument("--sequence", default=None, metavar="NAME-or-PATH",
                      help="what every trial maps (default synthetic: the built-in living "
                           "room, 60 frames at 320x240; any reader's path works, the 3D "
                           "objectives need a sequence with ground-truth voxels)")
    what.add_argument("--reader", default=None, metavar="NAME",
                      help="the sequence's reader (default: detected from the path)")
    what.add_argument("-r", "--reader-option", type=key_value, action="append", default=[],
                      metavar="KEY=VALUE",
                      help="a reader option, repeatable (e.g. -r frames=120 -r laps=2 for the "
                           "synthetic room)")
    what.add_argument("--frames", type=nonnegative_int, default=None, metavar="N",
                      help="map the first N frames only")
    what.add_argument("--segmenter", default=None, metavar="NAME",
                      help="whose observations every map reads (default oracle: ground truth "
                           "with seeded noise at -s accuracy=...; a network needs --weights)")
    what.add_argument("-s", "--segmenter-option", type=key_value, action="append", default=[],
                      metavar="KEY=VALUE", help="a segmenter option, repeatable (e.g. -s "
                                                "accuracy=0.9 for the oracle)")
    what.add_argument("--weights", type=Path, default=None, metavar="FILE",
                      help="the network's trained weights")
    run = p.add_argument_group("the study")
    run.add_argument("--out", type=Path, required=True, metavar="DIR",
                     help="the study folder (its report, and study.db unless --storage)")
    run.add_argument("--trials", type=nonnegative_int, default=None, metavar="N",
                     help=f"complete trials the study ends with (default {DEFAULT_TRIALS}; with "
                          f"--resume the study's, or a new target; 0 writes the report only)")
    run.add_argument("--resume", action="store_true",
                     help="continue the study in --out (or --storage): no finished trial runs "
                          "again, an interrupted one runs again with the same parameters")
    run.add_argument("--storage", default=None, metavar="URL",
                     help="an SQLAlchemy URL for the study (e.g. postgresql://host/db, to share "
                          "it between machines); default sqlite:///OUT/study.db")
    run.add_argument("--study", default=None, metavar="NAME",
                     help="the study's name in the storage (default explore)")
    run.add_argument("--executor", choices=("local", "ray"), default="local",
                     help="local (default: trials one at a time in this process) or ray (one "
                          "worker per timing node of the cluster, each alone on its node)")
    run.add_argument("--address", default=None, metavar="ADDR",
                     help="with --executor ray: the cluster to join (default: a local one)")
    labels = p.add_argument_group(
        "how the answer moves with the labels",
        "after the trials, the answer's key points (the paper's point, the best trial within "
        "the mIoU tolerance) and their baselines are mapped again with the oracle's per-pixel, "
        "fitted and noise-free labels and a network's; on by default where the study's "
        "segmenter is the oracle or a network and the sequence has ground truth; stored in "
        "the study (docs/explore.md)")
    labels.add_argument("--no-sensitivity", action="store_true",
                        help="skip it (the report then has no such section)")
    labels.add_argument("--sensitivity-weights", type=Path, default=None, metavar="FILE",
                        help="a trained network whose labels are one more source (kept in the "
                             "study: a resume uses it again)")
    labels.add_argument("--sensitivity-segmenter", default=None, metavar="NAME",
                        help="that network's segmenter (default: the model its card names)")
    p.set_defaults(run=run_command)


def _space(args: argparse.Namespace) -> Any:
    from evsmap.explore.space import load_space, shipped_space, shipped_updaters

    if args.space is not None:
        return load_space(args.space)
    path = shipped_space(args.updater)
    if path is None:
        raise EvsmapError(f"--updater {args.updater}: no shipped space (shipped: "
                          f"{', '.join(shipped_updaters())}); give one with --space FILE")
    return load_space(path)


def _inputs(args: argparse.Namespace) -> tuple[Any, tuple[str, ...]]:
    """The trials' inputs and the fields given on the command line."""
    from evsmap.explore.bench import DEFAULT_SYNTHETIC, Inputs
    from evsmap.registry import SEGMENTERS

    given = []
    sequence = args.sequence or "synthetic"
    options = dict(args.reader_option)
    if sequence == "synthetic" and args.reader in (None, "synthetic"):
        options = {**DEFAULT_SYNTHETIC, **options}
    segmenter = args.segmenter or "oracle"
    if segmenter not in SEGMENTERS:
        raise EvsmapError(f"--segmenter {segmenter}: not a registered segmenter (evsmap list)")
    entry = SEGMENTERS.get(segmenter)
    for key, _ in args.segmenter_option:
        if key not in entry.options:
            raise EvsmapError(f"-s {key}: {segmenter} has no option {key!r} (its options: "
                              f"{', '.join(entry.options)})")
    if entry.takes.weights and args.weights is None:
        raise EvsmapError(f"--segmenter {segmenter}: a network needs --weights FILE (its "
                          f"trained weights: the classes of the maps depend on them)")
    if args.weights is not None and not args.weights.is_file():
        raise EvsmapError(f"--weights {args.weights}: no such file")
    for name, value in (("sequence", args.sequence), ("reader", args.reader),
                        ("reader_options", args.reader_option or None),
                        ("frames", args.frames), ("segmenter", args.segmenter),
                        ("segmenter_options", args.segmenter_option or None),
                        ("weights", args.weights)):
        if value is not None:
            given.append(name)
    inputs = Inputs(sequence=sequence, reader=args.reader, reader_options=options,
                    frames=args.frames, segmenter=segmenter,
                    segmenter_options=dict(args.segmenter_option),
                    weights=None if args.weights is None else str(args.weights.resolve()))
    return inputs, tuple(given)


def _check_out(args: argparse.Namespace) -> None:
    """A new study needs a new (or empty) folder; a resumed one its study."""
    from evsmap.explore.study import STUDY_FILE

    out: Path = args.out
    if out.exists() and not out.is_dir():
        raise EvsmapError(f"--out {out}: not a folder")
    holds_study = (out / STUDY_FILE).is_file()
    if args.resume:
        if args.storage is None and not holds_study:
            raise EvsmapError(f"--out {out}: no study to resume ({STUDY_FILE} is not there)")
        return
    if holds_study:
        raise EvsmapError(f"--out {out}: holds a study already; pass --resume to continue "
                          f"it, or another --out")
    if out.is_dir() and any(out.iterdir()):
        raise EvsmapError(f"--out {out}: exists and is not empty (a new study needs a new "
                          f"folder)")


def _request(args: argparse.Namespace) -> Any:
    from evsmap.explore.run import Request
    from evsmap.explore.study import STUDY_NAME, default_storage

    _check_out(args)
    if args.address is not None and args.executor != "ray":
        raise EvsmapError("--address: only with --executor ray")
    space = _space(args) if (args.space is not None or not args.resume) else None
    inputs, given = _inputs(args)
    trials = args.trials if args.trials is not None or args.resume else DEFAULT_TRIALS
    return Request(out=args.out, storage=args.storage or default_storage(args.out),
                   study=args.study or STUDY_NAME, trials=trials, resume=args.resume,
                   space=space, inputs=inputs, inputs_given=given)


def _sensitivity_network(args: argparse.Namespace) -> Any:
    """The ``--sensitivity-weights`` network (``None``: none given), checked before a trial
    runs."""
    from evsmap.explore.sensitivity import check_network

    given = [f for f, v in (("--sensitivity-weights", args.sensitivity_weights),
                            ("--sensitivity-segmenter", args.sensitivity_segmenter)) if v]
    if args.no_sensitivity and given:
        raise EvsmapError(f"{given[0]}: not with --no-sensitivity")
    if args.sensitivity_weights is None:
        if args.sensitivity_segmenter is not None:
            raise EvsmapError("--sensitivity-segmenter: only with --sensitivity-weights FILE")
        return None
    return check_network(args.sensitivity_segmenter, args.sensitivity_weights)


def _sensitivity_reason(args: argparse.Namespace, bench: Any, network: Any) -> str | None:
    """Why the study gets no sensitivity (``None``: it does); a network given for one that
    cannot have it is a usage error."""
    from evsmap.explore.sensitivity import applies

    if args.no_sensitivity:
        return "--no-sensitivity"
    reason = applies(bench.inputs, bench.has_truth())
    if reason is not None and network is not None:
        raise EvsmapError(f"--sensitivity-weights: no label sensitivity here ({reason})")
    return reason


def _sensitivity(opened: Any, bench: Any, network: Any, reason: str | None) -> Any:
    """The key points' records under each label source, and the header's line about them."""
    from evsmap.explore.sensitivity import run_sensitivity

    if reason is not None:
        _say(f"label sensitivity: skipped ({reason})")
        return None, f"skipped ({reason})"
    start = time.monotonic()
    records = run_sensitivity(opened.study, bench, network=network, say=_say)
    mapped = sum(r["from"] == "mapped" for r in records)
    took = time.monotonic() - start
    _say(f"label sensitivity: {len(records)} records in {took:.0f} s")
    return records, (f"{len(records)} records (key point x label source; {mapped} mapped "
                     f"again, at one time or another); this command spent {took:.0f} s on it")


def _listed(options: dict[str, Any]) -> str:
    return ", ".join(f"{k}={v}" for k, v in sorted(options.items()))


def _header(opened: Any, request: Any, elapsed: str) -> dict[str, str]:
    """The study's facts, printed first in its index.md."""
    from evsmap.environment import collect_environment

    space, inputs = opened.space, opened.config.inputs
    sequence = inputs["sequence"]
    if inputs["reader_options"]:
        sequence += f" ({_listed(inputs['reader_options'])})"
    if inputs.get("frames"):
        sequence += f", first {inputs['frames']} frames"
    options = _options(inputs["segmenter"], inputs["segmenter_options"])
    segmenter = f"{inputs['segmenter']} ({options})"
    if inputs.get("weights"):
        segmenter += f", weights {inputs['weights']}"
    sampler = f"{space.sampler} (seed {space.seed}; " + (
        f"population {space.population})" if space.sampler == "nsga2"
        else f"{space.startup_trials} random trials first)")
    env = collect_environment()
    return {"space": f"{space.path} (explored: {space.updater}; baseline: "
                     f"{space.baseline or 'none'}; reference: {space.reference})",
            "sequence": sequence, "segmenter": segmenter,
            "objectives the sampler steers by": ", ".join(
                f"{o.name} ({o.direction})" for o in space.objectives),
            "sampler": sampler, "target": f"{opened.config.trials} complete trials",
            "storage": f"{request.storage}, study {request.study!r}",
            "machine": f"{env['cpu']}, {env['instruction_set']}, {env['cpus']} CPUs "
                       f"(the rates are ratios to OctoMap C++ timed in the same process)",
            "this command": elapsed}


def _options(segmenter: str, given: dict[str, Any]) -> str:
    """The segmenter's options as it ran: those given, then its defaults (the oracle's accuracy
    is stated this way)."""
    from evsmap.registry import SEGMENTERS

    defaults = SEGMENTERS.get(segmenter).defaults() if segmenter in SEGMENTERS else {}
    values = {k: v for k, v in defaults.items()
              if k not in ("weights", "backend") and isinstance(v, (int, float, str, bool))}
    values.update(given)
    return ", ".join(f"{k}={v}" for k, v in values.items()) or "no options"


def run_command(args: argparse.Namespace) -> int:
    from evsmap.explore.bench import Bench, Inputs
    from evsmap.explore.results import trial_rows
    from evsmap.explore.run import open_study, run_local, run_ray
    from evsmap.explore.workers import Worker, counts
    from evsmap.interrupt import set_resume_hint
    from evsmap.report.explore import write_report

    request = _request(args)
    network = _sensitivity_network(args)
    bench = None
    if args.executor == "ray":
        from evsmap.runner.ray_executor import import_ray

        import_ray()  # a missing Ray is a usage error, before the study is made
    if not request.resume:  # the sequence, segmenter and objectives, before the study is made
        bench = Bench(request.space, request.inputs, say=_say)
        reason = _sensitivity_reason(args, bench, network)
    if args.storage is None:  # the study's SQLite file goes in the folder
        args.out.mkdir(parents=True, exist_ok=True)
    opened = open_study(request)
    if bench is None:
        bench = Bench(opened.space, Inputs(**opened.config.inputs), say=_say)
        reason = _sensitivity_reason(args, bench, network)
    args.out.mkdir(parents=True, exist_ok=True)
    again = f"evsmap explore --out {args.out} --resume" + (
        f" --storage {args.storage}" if args.storage else "") + (
        f" --study {args.study}" if args.study else "")
    set_resume_hint(f"every finished trial is kept; continue with `{again}`")
    say = _say
    n = counts(opened.study)
    say(f"study {request.study!r} in {request.storage}: {n.get('COMPLETE', 0)} of "
        f"{opened.config.trials} trials complete")
    start = time.monotonic()
    run = Worker.here().run
    if args.executor == "ray":
        done = run_ray(opened, address=args.address, out=args.out, say=say, run=run)
    else:
        done = run_local(opened, say=say, run=run, bench=bench)
    elapsed = f"{done} trials in {(time.monotonic() - start) / 60:.1f} min"
    records, said = _sensitivity(opened, bench, network, reason)
    header = {**_header(opened, request, elapsed), "label sensitivity": said}
    index, line = write_report(args.out, trial_rows(opened.study), opened.space,
                               header=header, sensitivity=records)
    from evsmap.explore.latest import record_latest

    record_latest(index, line)
    print(line)
    print(f"report: {index}")
    return 0


def _say(line: str) -> None:
    """A line of progress: on a terminal above the progress bar, else on stdout."""
    if sys.stderr.isatty():
        from tqdm import tqdm

        tqdm.write(line, file=sys.stderr)
    else:
        print(line, flush=True)
