"""Run the gate's workers: select workloads, measure each in fresh processes (this tree's, or
another checkout's through its own interpreter and import path), combine their records."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from evsmap.cache import CACHE_ENV
from evsmap.errors import EvsmapError
from evsmap.gate.prepare import CONTEXT_FILE, missing_input
from evsmap.gate.worker import THREAD_VARIABLES
from evsmap.gate.workloads import EMPTY_CACHE_WORKLOADS, Workload

WORKER_TIMEOUT_S = 600


# -- measuring ------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Checkout:
    """Where a worker's code comes from: this tree (the defaults: this interpreter, this
    process's import path) or another commit's files (``cwd`` first on the import path,
    ``env`` added to the environment, its own ``python`` where its dependencies differ)."""

    python: str = sys.executable
    cwd: Path | None = None
    env: dict[str, str] = field(default_factory=dict)


THIS_TREE = Checkout()


def run_worker(workload: Workload, context_file: Path, out_dir: Path, *, budget_s: float,
               threads: int, checkout: Checkout = THIS_TREE) -> dict[str, Any]:
    """Measure ``workload`` in a fresh Python process of ``checkout``; its record (or
    ``{"error": ...}``)."""
    out = out_dir / (workload.name.replace("/", "__") + ".json")
    env = {**os.environ, **checkout.env}
    for var in THREAD_VARIABLES:
        env[var] = str(threads)
    empty_cache = tempfile.mkdtemp(prefix="evsmap-gate-cache-", dir=out_dir) \
        if workload.name in EMPTY_CACHE_WORKLOADS else None
    if empty_cache:
        env[CACHE_ENV] = empty_cache
    out.unlink(missing_ok=True)  # a record there afterwards is this worker's (file times are
    # coarser than time.time_ns(): a quick worker's file could look older than its start)
    cmd = [checkout.python, "-m", "evsmap.gate.worker", "--workload", workload.name,
           "--context", str(context_file), "--out", str(out), "--budget", str(budget_s)]
    try:
        proc = subprocess.run(cmd, env=env, capture_output=True, text=True,
                              timeout=WORKER_TIMEOUT_S, cwd=checkout.cwd)
    except subprocess.TimeoutExpired:
        return {"name": workload.name, "error": f"timed out after {WORKER_TIMEOUT_S} s"}
    finally:
        if empty_cache:
            shutil.rmtree(empty_cache, ignore_errors=True)
    if not out.exists():
        tail = (proc.stderr or "").strip().splitlines()[-1:] or [f"exit {proc.returncode}"]
        return {"name": workload.name, "error": f"the worker died: {tail[0]}"}
    record = json.loads(out.read_text())
    record["description"] = workload.description
    return record


def measure_all(workloads: Sequence[Workload], context: dict[str, Any], workdir: Path, *,
                budget_s: float, repeats: int = 1,
                progress: bool = True) -> dict[str, list[dict[str, Any]]]:
    """Every workload measured in ``repeats`` fresh processes, in rounds (all workloads once,
    then again), so a slow spell of the machine falls on different workloads' repeats; a
    progress bar on stderr. Missing inputs give one ``{"skipped": why}`` record."""
    from tqdm import tqdm

    threads = int(context["threads"])
    results: dict[str, list[dict[str, Any]]] = {}
    context_file = workdir / CONTEXT_FILE
    context_file.write_text(json.dumps(context))
    jobs = [w for _ in range(repeats) for w in workloads]
    bar = tqdm(jobs, desc="gate", unit="process", file=sys.stderr, disable=not progress,
               leave=False)
    for workload in bar:
        bar.set_postfix_str(workload.name)
        why = missing_input(workload, context)
        if why:
            results[workload.name] = [{"name": workload.name, "skipped": why}]
            continue
        t0 = time.perf_counter()
        record = run_worker(workload, context_file, workdir, budget_s=budget_s,
                            threads=threads)
        record["seconds"] = time.perf_counter() - t0
        results.setdefault(workload.name, []).append(record)
    return results


def outside_band(rows: Sequence[Any], workloads: Sequence[Workload]) -> list[Workload]:
    """The workloads whose time ratio or peak a first pass put outside the band (``FAIL`` or
    ``better``): the ones worth measuring again before a verdict. Count changes and errors are
    not noise and are not re-measured."""
    names = {r.workload for r in rows
             if r.measure in ("time_ratio", "peak_rss_bytes") and r.verdict in ("FAIL", "better")}
    return [w for w in workloads if w.name in names]


def pick_cpu(cpu: int | None) -> int:
    """The CPU every worker is pinned to: ``cpu``, else the lowest this process may use.

    Raises:
        EvsmapError: ``cpu`` is not one this process may use.
    """
    allowed = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else [0]
    if cpu is None:
        return allowed[0]
    if cpu not in allowed:
        raise EvsmapError(f"--cpu {cpu}: not a CPU this process may use "
                          f"({', '.join(map(str, allowed))})")
    return cpu


def combine(records: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """One workload's processes as one record: the median ``time_ratio`` and
    ``peak_rss_bytes``, the counts (an error if two processes disagree: the workload is not
    deterministic), every process's ratio and peak under ``processes``."""
    bad = [r for r in records if "error" in r or "skipped" in r]
    if bad:
        return dict(bad[0])
    first = records[0]
    out = dict(first)
    out["time_ratio"] = float(np.median([r["time_ratio"] for r in records]))
    out["peak_rss_bytes"] = int(np.median([r["peak_rss_bytes"] for r in records]))
    out["seconds"] = float(sum(r.get("seconds", 0.0) for r in records))
    out["processes"] = [{"time_ratio": r["time_ratio"], "peak_rss_bytes": r["peak_rss_bytes"],
                         "time_ratio_rel_iqr": r.get("time_ratio_rel_iqr"),
                         "workload_ms": r.get("workload_ms"),
                         "calibration_ms": r.get("calibration_ms")} for r in records]
    for r in records[1:]:
        if r.get("counts") != first.get("counts"):
            return {"name": first["name"], "error": f"the exact counts differ between two "
                    f"processes ({first.get('counts')} and {r.get('counts')}): the workload "
                    f"is not deterministic"}
    return out
