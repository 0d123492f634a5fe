"""Run the gate: prepare the shared inputs, measure every selected workload in a fresh process,
read and write the baseline file."""

from __future__ import annotations

import fnmatch
import json
import math
import os
import subprocess
import sys
import time
from collections.abc import Callable, Iterable, Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from evsmap.errors import DataFormatError, EvsmapError
from evsmap.gate.worker import THREAD_VARIABLES
from evsmap.gate.workloads import (
    MAP_NETWORK,
    NETWORK_SIZE,
    UPDATE_FRAMES,
    Workload,
    tum_sequence,
)

BASELINE_FORMAT = 1
DEFAULT_BASELINE = Path("benchmarks") / "baseline.json"
WORKER_TIMEOUT_S = 600


# -- the baseline file ---------------------------------------------------------------------------


def read_baseline(path: str | os.PathLike[str]) -> dict[str, Any]:
    """A baseline file: ``{"format", "machine", "settings", "workloads": {name: entry}}``.

    Raises:
        DataFormatError: the file cannot be read or is not a baseline (names the file).
    """
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise DataFormatError(f"{path}: no such baseline file (make one with "
                              f"`evsmap gate --update --baseline {path}`)") from None
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise DataFormatError(f"{path}: not a readable JSON baseline ({exc})") from None
    except RecursionError:
        raise DataFormatError(f"{path}: not a readable JSON baseline (nested too deeply)") \
            from None
    workloads = data.get("workloads") if isinstance(data, dict) else None
    if not isinstance(workloads, dict):
        raise DataFormatError(f"{path}: no top-level \"workloads\" object")
    for name, entry in workloads.items():
        if not isinstance(entry, dict):
            raise DataFormatError(f"{path}: workload {name!r} is not an object")
        for key in ("time_ratio", "peak_rss_bytes"):
            value = entry.get(key)
            if not _finite_nonnegative(value):
                raise DataFormatError(f"{path}: workload {name!r} has no valid {key!r} (a "
                                      f"finite number >= 0)")
    return data


def _finite_nonnegative(value: Any) -> bool:
    if not isinstance(value, (int, float)) or isinstance(value, bool):
        return False
    try:
        return math.isfinite(value) and value >= 0
    except OverflowError:  # an integer beyond the float range
        return False


def write_baseline(path: str | os.PathLike[str], data: dict[str, Any]) -> None:
    from evsmap.fileio import atomic_write_text

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(path, json.dumps(data, indent=1, sort_keys=False) + "\n")


def machine_info(threads: int) -> dict[str, Any]:
    """Facts about this machine and its libraries, and ``kind``: what must match for a
    baseline to hold here (CPU model, the vector extensions the kernels pick, cores, python
    and library versions)."""
    from evsmap.environment import describe
    from evsmap.measure.speed import library_versions

    info: dict[str, Any] = {**describe(), **library_versions(), "threads": threads}
    info["kind"] = machine_kind(info)
    return info


def machine_kind(info: dict[str, Any]) -> str:
    """A short fingerprint of what a baseline's figures depend on (see :func:`machine_info`)."""
    import hashlib

    keys = ("cpu", "cpus", "machine", "instruction_set", "cpu_flags", "python", "torch",
            "onnxruntime", "numpy")
    text = json.dumps({k: info.get(k) for k in keys}, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:12]


def updated_baseline(old: dict[str, Any] | None, measured: dict[str, dict[str, Any]],
                     settings: dict[str, Any]) -> dict[str, Any]:
    """``old`` with the measured workloads replaced (others kept), new machine facts."""
    from evsmap.gate.compare import entry_of

    workloads = dict((old or {}).get("workloads", {}))
    for name, rec in measured.items():
        if "error" not in rec and "skipped" not in rec:
            workloads[name] = entry_of(rec)
    return {"format": BASELINE_FORMAT,
            "updated": datetime.now(UTC).isoformat(timespec="seconds"),
            "machine": machine_info(int(settings.get("threads", 1))),
            "settings": settings,
            "workloads": dict(sorted(workloads.items()))}


# -- selection ----------------------------------------------------------------------------------


def select(workloads: Sequence[Workload], patterns: Sequence[str] | None) -> list[Workload]:
    """The workloads whose name matches one of ``patterns`` (exact names or shell patterns,
    ``net/*``); all of them without patterns.

    Raises:
        EvsmapError: a pattern matches no workload (names the pattern and the known ones).
    """
    if not patterns:
        return list(workloads)
    chosen = []
    for pattern in patterns:
        hit = [w for w in workloads if fnmatch.fnmatchcase(w.name, pattern)]
        if not hit:
            known = ", ".join(w.name for w in workloads)
            raise EvsmapError(f"--only {pattern!r} matches no gate workload (known: {known})")
        chosen += [w for w in hit if w not in chosen]
    return chosen


def selected_names(names: Iterable[str], patterns: Sequence[str] | None) -> set[str]:
    return {n for n in names
            if not patterns or any(fnmatch.fnmatchcase(n, p) for p in patterns)}


# -- shared inputs --------------------------------------------------------------------------------


def _sample(folder: str) -> tuple[str | None, str | None]:
    from evsmap.paths import default_data_root

    path = default_data_root() / folder
    if path.exists():
        return str(path), None
    return None, (f"needs the sample {path} (data root: $EVSMAP_DATA_ROOT, ../shared/data or "
                  f"~/.cache/evsmap/data; `evsmap datasets fetch`)")


def discover(*, threads: int) -> tuple[dict[str, Any], dict[str, Any]]:
    """The gate context (the samples' paths, the networks and the updaters registered here)
    and the seeded networks built to find out which segmenters are networks."""
    import torch

    from evsmap.registry import SEGMENTERS, UPDATERS

    context: dict[str, Any] = {"threads": threads, "networks": {},
                               "updaters": list(UPDATERS.names()), "missing": {},
                               "observations": None}
    context["tum"], context["missing"]["tum"] = _sample("tum_fr1_xyz")
    context["bag"], context["missing"]["bag"] = _sample("ros/lidar_odometry.bag")
    context["missing"]["observations"] = context["missing"]["tum"]
    torch.set_num_threads(threads)
    built = {}
    for name in SEGMENTERS.names():
        if SEGMENTERS.get(name).extras.get("gate") is False:
            # a plug-in that asks not to be gated (the compared networks of Tables I-II:
            # timed beside FEAGNet in every reproduce run; several are 100-500 GFLOPs)
            context.setdefault("not_gated", []).append(name)
            continue
        torch.manual_seed(0)
        try:
            segmenter = SEGMENTERS.create(name)
        except EvsmapError as exc:  # a plug-in that cannot be built with its defaults
            context["missing"][f"net:{name}"] = str(exc)
            continue
        if segmenter.module is None:
            continue  # not a network (the oracle)
        context["networks"][name] = {"uses_depth": bool(segmenter.uses_depth)}
        built[name] = segmenter
    return context, built


def prepare_inputs(context: dict[str, Any], built: dict[str, Any],
                   workloads: Sequence[Workload], out: Path, *,
                   log: Callable[[str], Any] = lambda _: None) -> None:
    """What the selected workloads share, into ``context``: the ONNX exports (in the export
    cache shared across runs) and the top-3 of the seeded FEAGNet-V1 on the TUM frames the
    updaters integrate (``out/observations.npz``)."""
    import torch

    from evsmap.models.onnx_export import cached_onnx
    from evsmap.registry import SEGMENTERS

    for w in workloads:
        if w.kind == "net" and w.name.endswith("/onnxruntime"):
            name = w.name.split("/")[1]
            segmenter, info = built[name], context["networks"][name]
            log(f"ONNX export of {name} (cached across runs)")
            try:
                info["onnx"] = str(cached_onnx(segmenter.module,
                                               segmenter.example_inputs(*NETWORK_SIZE),
                                               segmenter.input_names, key=name))
            except EvsmapError as exc:
                info["onnx_error"] = str(exc)
    if context["tum"] and any(w.kind == "update" for w in workloads):
        log(f"top-3 of the seeded {MAP_NETWORK} on {len(UPDATE_FRAMES)} TUM frames")
        torch.manual_seed(0)
        segmenter = SEGMENTERS.create(MAP_NETWORK)
        seq = tum_sequence(context["tum"])
        obs = [segmenter.predict(seq[i]) for i in UPDATE_FRAMES]
        path = out / "observations.npz"
        np.savez(path, classes=np.stack([o.classes for o in obs]),
                 probs=np.stack([o.probs for o in obs]), num_classes=obs[0].num_classes)
        context["observations"] = str(path)


def missing_input(workload: Workload, context: dict[str, Any]) -> str | None:
    """Why ``workload`` cannot run here, or None."""
    for need in workload.needs:
        if need in ("tum", "bag") and not context.get(need):
            return context["missing"].get(need) or f"needs {need}"
        if need == "observations" and not context.get("observations"):
            return context["missing"].get("observations") or "no observations were prepared"
    return None


# -- measuring ------------------------------------------------------------------------------------


def run_worker(workload: Workload, context_file: Path, out_dir: Path, *, budget_s: float,
               threads: int) -> dict[str, Any]:
    """Measure ``workload`` in a fresh Python process; its record (or ``{"error": ...}``)."""
    out = out_dir / (workload.name.replace("/", "__") + ".json")
    env = dict(os.environ)
    for var in THREAD_VARIABLES:
        env[var] = str(threads)
    cmd = [sys.executable, "-m", "evsmap.gate.worker", "--workload", workload.name,
           "--context", str(context_file), "--out", str(out), "--budget", str(budget_s)]
    try:
        proc = subprocess.run(cmd, env=env, capture_output=True, text=True,
                              timeout=WORKER_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        return {"name": workload.name, "error": f"timed out after {WORKER_TIMEOUT_S} s"}
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
    context_file = workdir / "context.json"
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
