"""Measure one gate workload in this (fresh) process: ``python -m evsmap.gate.worker``.

The phases, in order:

1. import, load every registered plug-in (the readers, segmenters and updaters and what they
   import: numba, llvmlite, rosbags, OctoMap), load the workload's inputs
   (:class:`evsmap.gate.workloads.Job`), warm its compiled kernels on a small input, make the
   calibration buffers and run the calibration once;
2. collect garbage, return freed heap to the system, take the idle RSS, fix glibc's mmap
   threshold at its floor (128 KiB: every larger block is mapped on allocation and unmapped
   on free, so the peak is what the workload held, not what the allocator kept; see
   :mod:`evsmap.measure.memory`) and reset the peak;
3. build the workload and run it once, untimed (lazy initialisation, compiled kernels); the
   peak RSS over this phase less the idle RSS, less the file pages mapped over the phase (the
   code of the libraries the workload first ran, whose count depends on the page cache, not on
   the code: :mod:`evsmap.measure.memory`), is ``peak_rss_bytes``; the peak with them is
   recorded beside it (``peak_rss_total_bytes``, ``file_rss_growth_bytes``);
4. fix the mmap threshold at glibc's ceiling (32 MiB, where its dynamic threshold settles in a
   long run, so blocks are reused rather than mapped afresh on every run); a network's pass on a
   GPU is first run until its speed settles, as ``evsmap speed`` does; then time
   ``calibration, workload`` pairs (each workload run timed as
   :mod:`evsmap.measure.pass_timing` defines: the host clock on the CPU, CUDA events on a GPU,
   the wall clock and the host's dispatch beside, recorded as ``timing``), ending with a
   calibration, until the time budget is spent (at least ``min_pairs``, at most
   ``max_pairs``); each workload time is divided by the mean of the calibrations just before
   and after it, and ``time_ratio`` is the median of those ratios; the RSS growth over this
   phase is recorded (a workload that keeps memory from run to run shows it);
5. the exact counts of the last run.

The result is one JSON object written to ``--out``.
"""

from __future__ import annotations

import argparse
import gc
import json
import math
import os
import sys
import time
import traceback
from pathlib import Path
from typing import Any

THREAD_VARIABLES = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS",
                    "NUMBA_NUM_THREADS")


def measure(name: str, context: dict[str, Any], *, budget_s: float, min_pairs: int,
            max_pairs: int) -> dict[str, Any]:
    """Run workload ``name`` through the phases of the module docstring; returns the record."""
    import numpy as np
    import torch

    from evsmap.gate.calibration import Calibration
    from evsmap.gate.workloads import make_job, plan
    from evsmap.measure.memory import (
        MMAP_THRESHOLD_MAX,
        MMAP_THRESHOLD_MIN,
        current_rss,
        fixed_mmap_threshold,
        peak_rss,
        reset_peak,
        resident_parts,
        trim_heap,
    )
    from evsmap.measure.timing_policy import median_ci, relative_half_width

    threads = int(context.get("threads", 1))
    cpus = context.get("cpus")
    if cpus and hasattr(os, "sched_setaffinity"):  # no migration between unequal cores
        os.sched_setaffinity(0, {int(c) for c in cpus})
    torch.set_num_threads(threads)
    from evsmap.registry import list_readers

    list_readers()  # imports every plug-in: their libraries are the idle process's, not the run's
    job = make_job(name, context)
    job.warm()
    kinds = {w.name: w.calibration for w in plan(context)}
    calibration = Calibration(kinds.get(name, "compute"), device=context.get("device", "cuda"))
    calibration.run()
    gc.collect()
    trim_heap()
    idle = current_rss()
    idle_parts = resident_parts()
    allocator = "glibc, fixed mmap threshold" if fixed_mmap_threshold(MMAP_THRESHOLD_MIN) \
        else "not glibc: the C library's defaults"
    scope = "workload" if reset_peak() else "process"

    t0 = time.perf_counter()
    job.build()
    t1 = time.perf_counter()
    job.run()
    first = time.perf_counter() - t1
    build = t1 - t0
    peak = max(peak_rss(), current_rss())
    end_parts = resident_parts()
    file_growth = max(0, end_parts["file"] - idle_parts["file"]) \
        if idle_parts and end_parts else 0
    fixed_mmap_threshold(MMAP_THRESHOLD_MAX)
    timing, timer, settled = _pass_timing(name, context, job)
    before = current_rss()
    pairs = max(min_pairs, min(max_pairs, math.ceil(budget_s / max(first, 1e-3))))
    cal = [calibration.run()]
    parts = [calibration.parts]
    work = []
    for _ in range(pairs):
        work.append(timer(job.run))
        cal.append(calibration.run())
        parts.append(calibration.parts)
    growth = current_rss() - before
    counts = job.counts()
    median, low, high = median_ci(work)  # the workload's own median time, as speed states it
    cal_arr = np.asarray(cal)
    around = (cal_arr[:-1] + cal_arr[1:]) / 2.0
    ratios = np.asarray(work) / around
    q25, q50, q75 = np.percentile(ratios, [25, 50, 75])
    return {
        "name": name, "time_ratio": float(q50), "time_ratio_rel_iqr": float((q75 - q25) / q50),
        "pairs": pairs, "workload_ms": float(np.median(work) * 1e3),
        "calibration": calibration.kind, "calibration_ms": float(np.median(cal_arr) * 1e3),
        "calibration_parts_ms": {k: float(np.median([p[k] for p in parts]) * 1e3)
                                 for k in parts[0]},
        "first_run_ms": first * 1e3, "build_ms": build * 1e3,
        "peak_rss_bytes": int(max(0, peak - idle - file_growth)),
        "peak_rss_total_bytes": int(max(0, peak - idle)),
        "file_rss_growth_bytes": int(file_growth), "idle_rss_bytes": int(idle),
        "idle_rss_parts": idle_parts,
        "peak_scope": scope, "allocator": allocator, "timed_rss_growth_bytes": int(growth),
        "threads": threads, "cpus": sorted(os.sched_getaffinity(0))
        if hasattr(os, "sched_getaffinity") else None, "counts": counts,
        "workload_ci_ms": [low * 1e3, high * 1e3],
        "workload_rel_ci": relative_half_width(median, low, high),
        "timing": timing.as_dict(), "wall_ms": float(np.median(timer.walls) * 1e3),
        "dispatch_ms": float(np.median(timer.dispatches) * 1e3),
        "settle": settled.as_dict() if settled else None,
    }


def _pass_timing(name: str, context: dict[str, Any], job: Any) -> tuple[Any, Any, Any]:
    """The timing definition of the workload (:mod:`evsmap.measure.pass_timing`, with the
    gate's threads and pinned CPU), its pass timer, and on a GPU the settling of its speed."""
    from evsmap.devices import PassTimer, settle
    from evsmap.measure.pass_timing import pass_timing

    device = context.get("device", "cpu") if name.startswith("net/") else "cpu"
    cpus = context.get("cpus")
    timing = pass_timing(device, int(context.get("threads", 1)), cpus=cpus, pin=bool(cpus))
    timer = PassTimer(device)
    settled = settle(job.run, timer) if timing.settle else None
    timer.reset()
    return timing, timer, settled


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m evsmap.gate.worker")
    p.add_argument("--workload", required=True)
    p.add_argument("--context", required=True, type=Path)
    p.add_argument("--out", required=True, type=Path)
    p.add_argument("--budget", type=float, default=4.0)
    p.add_argument("--min-pairs", type=int, default=5)
    p.add_argument("--max-pairs", type=int, default=25)
    args = p.parse_args(argv)
    context = json.loads(args.context.read_text())
    try:
        record = measure(args.workload, context, budget_s=args.budget,
                         min_pairs=args.min_pairs, max_pairs=args.max_pairs)
    except Exception as exc:  # noqa: BLE001 - reported to the parent as the workload's error
        from evsmap.errors import EvsmapError

        detail = "" if isinstance(exc, EvsmapError) else "\n" + traceback.format_exc()
        record = {"name": args.workload, "error": f"{type(exc).__name__}: {exc}",
                  "traceback": detail}
    args.out.write_text(json.dumps(record, indent=1))
    return 0


if __name__ == "__main__":
    # one intra-op thread everywhere unless the parent set otherwise: before numpy or torch load
    for var in THREAD_VARIABLES:
        os.environ.setdefault(var, "1")
    sys.exit(main())
