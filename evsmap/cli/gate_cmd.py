"""``evsmap gate``: regression gates on speed and memory against a committed baseline."""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from evsmap.cli.options import nonnegative_int, positive_float, positive_int
from evsmap.cli.precision import check_device, device_arg
from evsmap.errors import EvsmapError


def add_parser(sub: argparse._SubParsersAction) -> None:
    from evsmap.gate.baseline import DEFAULT_BASELINE
    from evsmap.gate.compare import MEMORY_THRESHOLD, TIME_THRESHOLD

    p = sub.add_parser(
        "gate", help="regression gates on speed and memory against a baseline",
        description="Measure every workload (each network's forward pass on torch and ONNX "
                    "Runtime at 480x640, each map updater on real TUM frames at 5 and 2 cm, "
                    "`evsmap map` end to end, the TUM and ROS bag readers, the report build) "
                    "in a fresh process: its time as a ratio to a calibration workload "
                    "alternated with it, its peak resident memory above the idle process, and "
                    "exact counts. Compare with the baseline's figures of this machine kind "
                    "or, where the baseline has none, with the commit that last changed the "
                    "baseline file, measured beside this tree in the same run (--against): a "
                    "count that "
                    f"changed, a time ratio more than {TIME_THRESHOLD:.0%} or a peak more than "
                    f"{MEMORY_THRESHOLD:.0%} above it fails (exit 1). See docs/gates.md.")
    p.add_argument("--baseline", type=Path, default=DEFAULT_BASELINE, metavar="FILE",
                   help=f"the baseline file, figures per machine kind (default "
                        f"{DEFAULT_BASELINE})")
    p.add_argument("--against", metavar="REF",
                   help="measure this commit, branch or tag of the baseline's git checkout "
                        "beside this tree in the same run and judge the paired ratios (default "
                        "when the baseline has no figures of this machine kind: the commit "
                        "that last changed the baseline file)")
    p.add_argument("--stored", action="store_true",
                   help="never pair: on a machine kind the baseline has no figures for, "
                        "compare only the exact counts that do not go through floating point")
    p.add_argument("--update", action="store_true",
                   help="write the measured workloads into the baseline as this machine "
                        "kind's figures (its other workloads and the other kinds are kept) "
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
                        "one process's or one slow spell's luck); with a reference: pairs of "
                        "processes per workload in the first pass (default 1)")
    p.add_argument("--confirm", type=nonnegative_int, default=4, metavar="N",
                   help="a workload whose time or peak is outside the band after the first "
                        "pass is measured in N more processes (pairs, with a reference) and "
                        "judged on the median of all (default 4: a verdict is then the median "
                        "of five, like the baseline; 0 judges the first pass)")
    p.add_argument("--cpu", type=int, metavar="K",
                   help="pin every worker to this CPU (default: the lowest this process may "
                        "use; two cores of a VM can differ in speed by 25 %%, and a process "
                        "that migrates between them mixes both)")
    p.add_argument("--results", type=Path, metavar="FILE",
                   help="also write every measurement (all repeats' summaries) as JSON here "
                        "(a new file unless --overwrite)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace an existing --results file (once the new one is complete)")
    p.add_argument("--device", type=device_arg, default="cpu", metavar="DEVICE",
                   help="cpu (default: every workload) or cuda[:N]: each network's forward "
                        "pass on that GPU, timed against a GPU matmul calibration, compared "
                        "with the baseline's figures of this GPU kind (GPU model, CUDA, cuDNN, "
                        "driver; record them once with --update); docs/gates.md")
    p.add_argument("--json", action="store_true",
                   help="print the verdicts and measurements as JSON instead of the table")
    p.set_defaults(run=run)


@dataclass
class Comparison:
    """What the gate compares with, and why: ``mode`` is ``record`` (``--update``), ``stored``
    (the baseline's figures of this machine kind), ``counts`` (another kind's figures, exact
    counts only) or ``paired`` (``commit`` measured beside this tree); ``entry`` the stored
    figures used."""

    mode: str
    why: str
    entry: dict[str, Any] | None = None
    commit: str | None = None
    root: Path | None = None


def claim(args: argparse.Namespace) -> None:
    """The files the gate writes, checked before anything is measured: ``--results`` (a new
    file unless ``--overwrite``; never the baseline) and, with ``--update``, the baseline (a
    file that can be written); and a ``--baseline`` that is a folder; options that exclude each
    other.

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
    for a, b in (("against", "update"), ("against", "stored"), ("stored", "update")):
        if getattr(args, a) and getattr(args, b):
            raise EvsmapError(f"--{a} and --{b} exclude each other")
    if args.results is not None:
        if os.path.abspath(args.results) == os.path.abspath(args.baseline):
            raise EvsmapError(f"--results {args.results} is the baseline file: write the "
                              "measurements to another file")
        claim_outputs([Output("--results", args.results)], overwrite=args.overwrite)
    if args.update:
        check_writable(Output("--baseline", args.baseline))


def choose_comparison(args: argparse.Namespace, data: dict[str, Any] | None,
                      here: dict[str, Any]) -> Comparison:
    """The comparison this run makes (see :class:`Comparison`), with its reason in words.

    Raises:
        EvsmapError: ``--against`` outside a git checkout or naming no commit; ``--update
            --only`` on a kind the baseline has no figures for.
    """
    from evsmap.gate.baseline import describe_machine, kind_entry, newest_entry
    from evsmap.gitinfo import is_shallow_boundary, last_commit_of, resolve_commit, toplevel
    from evsmap.paths import REPO_ROOT

    this = describe_machine(here)
    entry = kind_entry(data, here["kind"])
    if args.update:
        if args.only and entry is None and data is not None:
            raise EvsmapError(f"{args.baseline} has no figures of this machine kind ({this}) "
                              f"yet: record every workload the first time (no --only)")
        return Comparison("record", f"recording this machine kind's figures ({this}) in "
                                    f"{args.baseline}", entry)
    root = toplevel(args.baseline) or toplevel(REPO_ROOT)
    if args.against:
        if root is None:
            raise EvsmapError(f"--against {args.against}: neither {args.baseline} nor evsmap is "
                              "in a git checkout, so there is no commit to measure")
        resolved = resolve_commit(root, args.against)
        return Comparison("paired", f"--against {args.against}: commit {resolved[:12]} measured "
                                    "beside this tree", commit=resolved, root=root)
    if entry is None and here.get("gpu"):
        raise EvsmapError(f"{args.baseline} has no figures of this GPU kind ({this}): record "
                          f"them once with evsmap gate --device {args.device} --update")
    if entry is not None:
        return Comparison("stored", f"the baseline has figures of this machine kind ({this}), "
                                    f"recorded {entry.get('updated', '?')} at commit "
                                    f"{str(entry.get('commit') or '?')[:12]}", entry)
    kinds = "; ".join(describe_machine(e.get("machine", {}))
                      for e in (data or {}).get("kinds", {}).values())
    none_here = f"the baseline has no figures of this machine kind ({this}; it has: {kinds})"
    counts_only = "only exact counts that do not go through floating point are compared"
    other = newest_entry(data)
    if args.stored:
        return Comparison("counts", f"--stored: {none_here}: {counts_only}", other)
    commit = last_commit_of(args.baseline)
    if commit is not None and root is not None and is_shallow_boundary(root, commit):
        return Comparison("counts", f"{none_here} and this clone is shallow, so the commit that "
                                    f"last changed {args.baseline} is not known (fetch the "
                                    f"history: `git fetch --unshallow`, or `fetch-depth: 0` in "
                                    f"GitHub Actions): {counts_only}", other)
    if commit is None or root is None:
        return Comparison("counts", f"{none_here} and {args.baseline} is not committed in a git "
                                    f"checkout, so no reference commit can be measured beside "
                                    f"this tree: {counts_only}", other)
    return Comparison("paired", f"{none_here}: commit {commit[:12]}, the last to change "
                                f"{args.baseline}, measured beside this tree", commit=commit,
                      root=root)



def _load(args: argparse.Namespace, here: dict[str, Any]) -> dict[str, Any] | None:
    from evsmap.gate.baseline import kind_entry, read_baseline

    if args.update and not args.baseline.exists():
        return None
    data = read_baseline(args.baseline)
    entry = kind_entry(data, here["kind"])
    threads = (entry or {}).get("settings", {}).get("threads")
    if threads is not None and (not isinstance(threads, int) or isinstance(threads, bool)):
        raise EvsmapError(f"{args.baseline}: this machine kind's settings.threads is not an "
                          f"integer ({threads!r})")
    if threads is not None and int(threads) != args.threads and not (args.update or
                                                                      args.against):
        raise EvsmapError(f"{args.baseline} was measured with --threads {threads} on this "
                          f"machine kind, not {args.threads}: time ratios differ with the "
                          f"thread count (pass --threads {threads})")
    return data


def run(args: argparse.Namespace) -> int:
    from evsmap.gate.baseline import machine_info
    from evsmap.gate.run import pick_cpu

    if args.list:
        return _list(args.device)
    claim(args)
    if args.device != "cpu":
        check_device(args.device, None)
        if args.against:
            raise EvsmapError(f"--against with --device {args.device}: a paired run measures "
                              f"the CPU workloads; a GPU kind compares with its stored figures "
                              f"(record them with --device {args.device} --update)")
    here = machine_info(args.threads, args.device)
    data = _load(args, here)
    comparison = choose_comparison(args, data, here)
    log = (lambda msg: sys.stderr.write(f"evsmap gate: {msg}\n")) if not args.json else \
        (lambda msg: None)
    cpu = pick_cpu(args.cpu)
    log(f"comparison: {comparison.mode}: {comparison.why}")
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="evsmap-gate-") as tmp:
        if comparison.mode == "paired":
            rows, results = _paired(args, comparison, cpu, Path(tmp), log)
        else:
            rows, results = _stored(args, comparison, cpu, Path(tmp), log)
    seconds = time.perf_counter() - t0
    from evsmap.gate.compare import summary, table

    passed, text = summary(rows, paired=comparison.mode == "paired") if rows else (True, "")
    results = {"seconds": seconds, "comparison": asdict(comparison) | {"entry": None},
               "rows": [r.as_dict() for r in rows], **results}
    if args.results:
        from evsmap.fileio import atomic_write_text

        atomic_write_text(args.results, json.dumps(results, indent=1, default=str))
    if args.update:
        text, passed = _record(args, data, here, results["workloads"]), True
    if args.json:
        print(json.dumps({"passed": passed, **results}, indent=1, default=str))
        return 0 if passed else 1
    print(f"comparison: {comparison.mode}: {comparison.why}")
    if rows:
        print(table(rows, against="reference" if comparison.mode == "paired" else "baseline"))
        print()
    print(text)
    print(f"({len(results['workloads'])} workloads in {seconds:.0f} s)")
    return 0 if passed else 1


def _list(device: str = "cpu") -> int:
    from evsmap.gate.prepare import discover
    from evsmap.gate.workloads import plan

    context, _ = discover(threads=1)
    for w in plan({**context, "device": device}):
        print(f"{w.name:44s} {w.calibration:8s} {w.description}")
    return 0


def _stored(args: argparse.Namespace, comparison: Comparison, cpu: int, tmp: Path,
            log: Callable[[str], Any]) -> tuple[list, dict[str, Any]]:
    """Measure this tree and hold it against the stored figures (``record``: just measure)."""
    from evsmap.gate.compare import compare
    from evsmap.gate.prepare import prepare
    from evsmap.gate.run import combine, measure_all, outside_band
    from evsmap.gate.workloads import selected_names

    context, chosen = prepare(tmp, threads=args.threads, cpu=cpu, patterns=args.only, log=log,
                              device=args.device)
    repeats = args.repeats or (5 if args.update else 1)
    base = {}
    if comparison.entry is not None and comparison.mode != "record":
        keep = selected_names(comparison.entry["workloads"], args.only)
        base = {k: v for k, v in comparison.entry["workloads"].items() if k in keep}
    log(f"measuring {len(chosen)} workloads, each in {repeats} fresh "
        f"process{'es' if repeats > 1 else ''} on CPU {cpu} "
        f"({args.threads} thread{'s' if args.threads > 1 else ''})")
    progress = not args.json
    runs = measure_all(chosen, context, tmp, budget_s=args.budget, repeats=repeats,
                       progress=progress)
    measured = {name: combine(records) for name, records in runs.items()}
    same = comparison.mode == "stored"
    if base and same and args.confirm > 0:
        doubtful = outside_band(compare(base, measured), chosen)
        if doubtful:
            log(f"{len(doubtful)} workload{'s' if len(doubtful) > 1 else ''} outside the band "
                f"after the first pass, measured {args.confirm} more times: "
                f"{', '.join(w.name for w in doubtful)}")
            more = measure_all(doubtful, context, tmp, budget_s=args.budget,
                               repeats=args.confirm, progress=progress)
            for name, records in more.items():
                runs[name] = runs[name] + records
                measured[name] = combine(runs[name])
    rows = compare(base, measured, same_machine=same) if comparison.entry is not None \
        and comparison.mode != "record" else []
    return rows, {"workloads": measured}


def _paired(args: argparse.Namespace, comparison: Comparison, cpu: int, tmp: Path,
            log: Callable[[str], Any]) -> tuple[list, dict[str, Any]]:
    """Measure the reference commit beside this tree and judge the paired ratios."""
    from evsmap.gate.compare import compare_paired
    from evsmap.gate.paired import paired_gate
    from evsmap.gate.run import combine

    assert comparison.commit is not None and comparison.root is not None
    run = paired_gate(source_root=comparison.root, commit=comparison.commit,
                      patterns=args.only, threads=args.threads, cpu=cpu,
                      budget_s=args.budget, rounds=args.repeats or 1, confirm=args.confirm,
                      workdir=tmp, progress=not args.json, log=log)
    only_here = {n: combine(r) for n, r in run.only_here.items()}
    rows = compare_paired(run.pairs, only_reference=run.only_reference, only_here=only_here)
    workloads = {n: combine([b for _, b in p]) for n, p in run.pairs.items()} | only_here
    reference = {n: combine([a for a, _ in p]) for n, p in run.pairs.items()}
    pairs = {n: [{"reference": _figures(a), "here": _figures(b)} for a, b in p]
             for n, p in run.pairs.items()}
    return rows, {"workloads": workloads, "reference": reference, "pairs": pairs,
                  "reference_environment": run.environment}


def _figures(record: dict[str, Any]) -> dict[str, Any]:
    return {k: record.get(k) for k in ("time_ratio", "peak_rss_bytes", "workload_ms",
                                       "calibration_ms", "seconds", "error", "skipped")
            if record.get(k) is not None}


def _record(args: argparse.Namespace, data: dict[str, Any] | None, here: dict[str, Any],
            measured: dict[str, dict[str, Any]]) -> str:
    """Write this machine kind's figures into the baseline; the line that says so."""
    from evsmap.gate.baseline import updated_baseline, write_baseline
    from evsmap.gitinfo import head_commit

    settings = {"threads": args.threads, "budget_s": args.budget, "device": args.device,
                "repeats": args.repeats or 5}
    write_baseline(args.baseline, updated_baseline(data, measured, settings, machine=here,
                                                   commit=head_commit()))
    errors = {k: v.get("error") or v.get("skipped") for k, v in measured.items()
              if "error" in v or "skipped" in v}
    return (f"{args.baseline}: {len(measured) - len(errors)} workloads recorded for this "
            f"machine kind ({here['kind']})"
            + "".join(f"\n  not recorded: {k}: {why}" for k, why in errors.items()))
