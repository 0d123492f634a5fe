"""The gate's baseline file: figures per machine kind, side by side.

Format 2 (``benchmarks/baseline.json``)::

    {"format": 2,
     "kinds": {"<kind>": {"updated", "commit", "machine", "settings", "workloads": {...}}}}

``<kind>`` is :func:`machine_kind`: a digest of what a time ratio or a peak depends on (CPU
model and vector extensions, cores, Python and library versions). Recording on one kind
(``evsmap gate --update``) replaces that kind's entry only; the other kinds' figures stay.
Format 1 (one machine's ``machine``, ``settings`` and ``workloads`` at the top level) is read as
a file with one kind.
"""

from __future__ import annotations

import json
import math
import os
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from evsmap.environment import collect_environment, read_environment
from evsmap.errors import DataFormatError

BASELINE_FORMAT = 2
DEFAULT_BASELINE = Path("benchmarks") / "baseline.json"
KIND_KEYS = ("cpu", "cpus", "machine", "instruction_set", "cpu_flags", "python")
KIND_LIBRARIES = ("torch", "onnxruntime", "numpy")
GPU_KIND_KEYS = ("gpu", "cuda", "cudnn", "driver_version", "clocks_max_sm")
"""The GPU facts a GPU kind's figures depend on (of :func:`evsmap.environment.collect_gpu`):
its model, CUDA, cuDNN, the driver and its maximum SM clock."""
"""The machine facts a baseline's figures depend on (of
:func:`evsmap.environment.collect_environment`, the libraries' from its ``versions``): their
digest is the machine kind."""


def machine_info(threads: int, device: str = "cpu") -> dict[str, Any]:
    """Facts about this machine and its libraries (:func:`~evsmap.environment.
    collect_environment` less the host and the commit, which the entry names as ``commit``),
    on a GPU ``device`` its facts (``gpu``: :func:`~evsmap.environment.collect_gpu`), and
    ``kind``: what must match for a baseline's figures to hold here (see :data:`KIND_KEYS`;
    on a GPU also :data:`GPU_KIND_KEYS`)."""
    info = collect_environment(threads)
    for key in ("host", "git_commit"):
        info.pop(key)
    if device != "cpu":
        from evsmap.environment import collect_gpu

        info["gpu"] = collect_gpu(device)
    info["kind"] = machine_kind(info)
    return info


def machine_kind(info: dict[str, Any]) -> str:
    """A short fingerprint of what a baseline's figures depend on (:data:`KIND_KEYS` and
    :data:`KIND_LIBRARIES`); ``info`` in either the current or a stored file's older keys
    (:func:`~evsmap.environment.read_environment`). The digest is of the facts as the first
    baselines flattened them (the libraries beside the machine), so a kind keeps its id."""
    import hashlib

    facts = read_environment(info)
    versions = facts.get("versions") or {}
    flat = {**{k: facts.get(k) for k in KIND_KEYS},
            **{k: versions.get(k) for k in KIND_LIBRARIES}}
    if facts.get("gpu"):  # a GPU kind (absent on the CPU, so a CPU kind keeps its id)
        flat["gpu"] = {k: facts["gpu"].get(k) for k in GPU_KIND_KEYS}
    text = json.dumps(flat, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:12]


def describe_machine(machine: dict[str, Any]) -> str:
    """``AMD EPYC, avx512-vnni, 2 cores`` (what a person reads to tell two kinds apart), and
    the GPU's model after it for a GPU kind."""
    gpu = (machine.get("gpu") or {}).get("gpu")
    return (f"{machine.get('cpu', '?')}, {machine.get('instruction_set', '?')}, "
            f"{machine.get('cpus', '?')} cores" + (f", {gpu}" if gpu else ""))


# -- reading -------------------------------------------------------------------------------------


def read_baseline(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The baseline file at ``path`` in format 2 (a format 1 file converted).

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
    if not isinstance(data, dict):
        raise DataFormatError(f"{path}: not a baseline (a JSON object with \"kinds\")")
    if "kinds" not in data and "workloads" in data:  # format 1: one machine
        machine = data.get("machine")
        machine = machine if isinstance(machine, dict) else {}
        kind = str(machine.get("kind") or "unknown")
        data = {"format": BASELINE_FORMAT,
                "kinds": {kind: {k: data[k] for k in ("updated", "machine", "settings",
                                                      "workloads") if k in data}}}
    kinds = data.get("kinds")
    if not isinstance(kinds, dict):
        raise DataFormatError(f"{path}: no top-level \"kinds\" object")
    for kind, entry in kinds.items():
        _check_kind(path, kind, entry)
        if "machine" in entry:
            entry["machine"] = read_environment(entry["machine"])
    return data


def _check_kind(path: Path, kind: str, entry: Any) -> None:
    if not isinstance(entry, dict):
        raise DataFormatError(f"{path}: machine kind {kind!r} is not an object")
    workloads = entry.get("workloads")
    if not isinstance(workloads, dict):
        raise DataFormatError(f"{path}: machine kind {kind!r} has no \"workloads\" object")
    for key in ("machine", "settings"):
        if not isinstance(entry.get(key, {}), dict):
            raise DataFormatError(f"{path}: machine kind {kind!r}: {key!r} is not an object")
    for name, figures in workloads.items():
        if not isinstance(figures, dict):
            raise DataFormatError(f"{path}: workload {name!r} is not an object")
        for key in ("time_ratio", "peak_rss_bytes"):
            if not _finite_nonnegative(figures.get(key)):
                raise DataFormatError(f"{path}: workload {name!r} has no valid {key!r} (a "
                                      f"finite number >= 0)")


def _finite_nonnegative(value: Any) -> bool:
    if not isinstance(value, (int, float)) or isinstance(value, bool):
        return False
    try:
        return math.isfinite(value) and value >= 0
    except OverflowError:  # an integer beyond the float range
        return False


def kind_entry(data: dict[str, Any] | None, kind: str) -> dict[str, Any] | None:
    """The figures ``data`` holds for machine kind ``kind``, or None."""
    return ((data or {}).get("kinds") or {}).get(kind)


def newest_entry(data: dict[str, Any] | None) -> dict[str, Any] | None:
    """The most recently recorded kind's figures (any kind), or None for an empty file."""
    entries = list(((data or {}).get("kinds") or {}).values())
    return max(entries, key=lambda e: str(e.get("updated", ""))) if entries else None


# -- writing -------------------------------------------------------------------------------------


def write_baseline(path: str | os.PathLike[str], data: dict[str, Any]) -> None:
    from evsmap.fileio import atomic_write_text

    atomic_write_text(Path(path), json.dumps(data, indent=1, sort_keys=False) + "\n")


def updated_baseline(old: dict[str, Any] | None, measured: dict[str, dict[str, Any]],
                     settings: dict[str, Any], *, machine: dict[str, Any],
                     commit: str | None) -> dict[str, Any]:
    """``old`` with this machine kind's entry updated: the measured workloads replaced (its
    other workloads kept; failed or skipped ones not recorded), the machine facts, settings and
    the commit measured. Other kinds are left as they were."""
    from evsmap.gate.compare import entry_of

    kinds = dict((old or {}).get("kinds") or {})
    kind = machine["kind"]
    workloads = dict((kinds.get(kind) or {}).get("workloads", {}))
    for name, rec in measured.items():
        if "error" not in rec and "skipped" not in rec:
            workloads[name] = entry_of(rec)
    kinds[kind] = {"updated": datetime.now(UTC).isoformat(timespec="seconds"),
                   "commit": commit, "machine": machine, "settings": settings,
                   "workloads": dict(sorted(workloads.items()))}
    return {"format": BASELINE_FORMAT, "kinds": dict(sorted(kinds.items()))}
