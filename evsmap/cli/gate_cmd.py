"""``evsmap gate``: regression gates on speed and memory against a committed baseline."""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

from evsmap.cli.options import nonnegative_int, positive_float, positive_int
from evsmap.errors import EvsmapError


def add_parser(sub: argparse._SubParsersAction) -> None:
    from evsmap.gate.compare import MEMORY_THRESHOLD, TIME_THRESHOLD
    from evsmap.gate.run import DEFAULT_BASELINE

    p = sub.add_parser(
        "gate", help="regression gates on speed and memory against a baseline",
        description="Measure every workload (each network's forward pass on torch and ONNX "
                    "Runtime at 480x640, each map updater on real TUM frames at 5 and 2 cm, "
                    "`evsmap map` end to end, the TUM and ROS bag readers, the report build) "
                    "in a fresh process: its time as a ratio to a calibration workload "
                    "alternated with it, its peak resident memory above the idle process, and "
                    "exact counts. Compare with the baseline: a count that changed, a time "
                    f"ratio more than {TIME_THRESHOLD:.0%} or a peak more than "
                    f"{MEMORY_THRESHOLD:.0%} above it fails (exit 1). See docs/gates.md.")
    p.add_argument("--baseline", type=Path, default=DEFAULT_BASELINE, metavar="FILE",
                   help=f"the baseline file (default {DEFAULT_BASELINE})")
    p.add_argument("--update", action="store_true",
                   help="write the measured workloads into the baseline (the others are kept) "
                        "instead of failing on them")
    p.add_argument("--only", nargs="+", action="extend", metavar="NAME",
                   help="measure only these workloads (names or shell patterns such as "
                        "'net/*' or 'update/*/2cm'; see --list)")
    p.add_argument("--list", action="store_true", help="list the workloads and exit")
    p.add_argument("--budget", type=positive_float, default=4.0, metavar="S",
                   help="seconds of timed runs per workload (at least 5 and at most 25 "
                        "calibration/workload pairs; default 4)")
    p.add_argument("--threads", type=positive_int, default=1, metavar="N",
                   help="intra-op threads of torch, ONNX Runtime and BLAS (default 1: the "
                        "least sensitive to a neighbour; must match the baseline's)")
    p.add_argument("--repeats", type=positive_int, metavar="N",
                   help="fresh processes per workload, in rounds, the median kept (default 1; "
                        "5 with --update, in rounds spread over the run, so a baseline is not "
                        "one process's or one slow spell's luck)")
    p.add_argument("--confirm", type=nonnegative_int, default=4, metavar="N",
                   help="a workload whose time or peak is outside the band after the first "
                        "pass is measured in N more processes and judged on the median of all "
                        "(default 4: a verdict is then the median of five processes, like the "
                        "baseline; 0 judges the first pass)")
    p.add_argument("--cpu", type=int, metavar="K",
                   help="pin every worker to this CPU (default: the lowest this process may "
                        "use; two cores of a VM can differ in speed by 25 %%, and a process "
                        "that migrates between them mixes both)")
    p.add_argument("--results", type=Path, metavar="FILE",
                   help="also write every measurement (all repeats' summaries) as JSON here "
                        "(a new file unless --overwrite)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace an existing --results file (once the new one is complete)")
    p.add_argument("--json", action="store_true",
                   help="print the verdicts and measurements as JSON instead of the table")
    p.set_defaults(run=run)


def claim(args: argparse.Namespace) -> None:
    """The files the gate writes, checked before anything is measured: ``--results`` (a new
    file unless ``--overwrite``; never the baseline) and, with ``--update``, the baseline (a
    file that can be written); and a ``--baseline`` that is a folder.

    Raises:
        EvsmapError: one line naming the option and the path.
    """
    from evsmap.cli.outputs import Output, check_writable, claim_outputs

    if args.baseline.is_dir():
        raise EvsmapError(f"--baseline {args.baseline}: is a folder, not a baseline file (give "
                          "the JSON file, e.g. benchmarks/baseline.json)")
    if args.overwrite and args.results is None:
        raise EvsmapError("--overwrite applies to --results FILE only (--update rewrites the "
                          "baseline without it)")
    if args.results is not None:
        if os.path.abspath(args.results) == os.path.abspath(args.baseline):
            raise EvsmapError(f"--results {args.results} is the baseline file: write the "
                              "measurements to another file")
        claim_outputs([Output("--results", args.results)], overwrite=args.overwrite)
    if args.update:
        check_writable(Output("--baseline", args.baseline))


def run(args: argparse.Namespace) -> int:
    from evsmap.gate.compare import compare, summary, table
    from evsmap.gate.run import (
        combine,
        discover,
        measure_all,
        outside_band,
        pick_cpu,
        prepare_inputs,
        read_baseline,
        select,
        selected_names,
        updated_baseline,
        write_baseline,
    )
    from evsmap.gate.workloads import plan

    if not args.list:
        claim(args)
    baseline = None
    if not (args.update and not args.baseline.exists()) and not args.list:
        baseline = read_baseline(args.baseline)
        threads = baseline.get("settings", {}).get("threads")
        if threads is not None and int(threads) != args.threads and not args.update:
            raise EvsmapError(f"{args.baseline} was measured with --threads {threads}, not "
                              f"{args.threads}: time ratios differ with the thread count (pass "
                              f"--threads {threads})")
    from evsmap.gate.run import machine_info

    here = machine_info(args.threads)
    theirs = (baseline or {}).get("machine", {})
    same = theirs.get("kind") == here["kind"] and theirs.get("threads", 1) == args.threads
    if args.update and args.only and baseline is not None and not same:
        raise EvsmapError(f"{args.baseline} was recorded on another machine kind or thread "
                          f"count: --update --only would mix figures of two machines in it; "
                          f"record every workload here (no --only) or use another --baseline")
    log = (lambda msg: sys.stderr.write(f"evsmap gate: {msg}\n")) if not args.json else \
        (lambda msg: None)
    cpu = pick_cpu(args.cpu) if not args.list else None
    t0 = time.perf_counter()
    context, built = discover(threads=args.threads)
    workloads = plan(context)
    if args.list:
        for w in workloads:
            print(f"{w.name:44s} {w.calibration:8s} {w.description}")
        return 0
    chosen = select(workloads, args.only)
    context["cpus"] = [cpu]
    if baseline is not None:  # after the checks above: a refusal is one line on its own
        their_isa = theirs.get("instruction_set", "instruction set not recorded")
        log(f"this machine: {here['cpu']}, {here['instruction_set']}; the baseline's: "
            f"{theirs.get('cpu', '?')}, {their_isa}"
            + ("" if same else " (another kind: only exact counts are compared)"))
    repeats = args.repeats or (5 if args.update else 1)
    base_entries = {}
    if baseline is not None:
        keep = selected_names(baseline["workloads"], args.only)
        base_entries = {k: v for k, v in baseline["workloads"].items() if k in keep}
    with tempfile.TemporaryDirectory(prefix="evsmap-gate-") as tmp:
        prepare_inputs(context, built, chosen, Path(tmp), log=log)
        del built
        log(f"measuring {len(chosen)} workloads, each in {repeats} fresh "
            f"process{'es' if repeats > 1 else ''} on CPU {context['cpus'][0]} "
            f"({args.threads} thread{'s' if args.threads > 1 else ''})")
        runs = measure_all(chosen, context, Path(tmp), budget_s=args.budget, repeats=repeats,
                           progress=not args.json)
        measured = {name: combine(records) for name, records in runs.items()}
        if base_entries and args.confirm > 0 and not args.update:
            doubtful = outside_band(compare(base_entries, measured), chosen)
            if doubtful:
                log(f"{len(doubtful)} workload{'s' if len(doubtful) > 1 else ''} outside the "
                    f"band after the first pass, "
                    f"measured {args.confirm} more times: "
                    f"{', '.join(w.name for w in doubtful)}")
                more = measure_all(doubtful, context, Path(tmp), budget_s=args.budget,
                                   repeats=args.confirm, progress=not args.json)
                for name, records in more.items():
                    runs[name] = runs[name] + records
                    measured[name] = combine(runs[name])
    seconds = time.perf_counter() - t0
    if baseline is not None and not same:
        log(f"the baseline is of another machine kind ({theirs.get('cpu')}, "
            f"{theirs.get('cpus')} cores, {', '.join(theirs.get('cpu_flags') or [])}) than this "
            f"one ({here['cpu']}, {here['cpus']} cores, {', '.join(here['cpu_flags'])})")
    rows = compare(base_entries, measured, same_machine=same) if baseline is not None else []
    passed, text = summary(rows) if rows else (True, "")
    if args.results:
        from evsmap.fileio import atomic_write_text

        atomic_write_text(args.results, json.dumps({"seconds": seconds, "workloads": measured},
                                                   indent=1))
    if args.update:
        settings = {"threads": args.threads, "budget_s": args.budget, "repeats": repeats}
        write_baseline(args.baseline, updated_baseline(baseline, measured, settings))
        errors = {k: v.get("error") or v.get("skipped") for k, v in measured.items()
                  if "error" in v or "skipped" in v}
        text = (f"{args.baseline}: {len(measured) - len(errors)} workloads recorded"
                + "".join(f"\n  not recorded: {k}: {why}" for k, why in errors.items()))
        passed = True
    if args.json:
        print(json.dumps({"passed": passed, "seconds": seconds,
                          "rows": [r.as_dict() for r in rows], "workloads": measured},
                         indent=1))
    else:
        if rows:
            print(table(rows))
            print()
        print(text)
        print(f"({len(chosen)} workloads in {seconds:.0f} s)")
    return 0 if passed else 1
