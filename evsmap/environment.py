"""Facts about the machine a measurement ran on: the one place they are read.

:func:`collect_environment` is the one record of them (as detectron2's ``collect_env``): every
run record, weights card, gate baseline and Ray node takes its facts from it, one key per fact:

==================  =====================================================================
``python``          Python's version
``machine``         the architecture (``platform.machine()``)
``cpu``             the CPU's model name (:func:`cpu_model`)
``cpus``            logical CPUs (``os.cpu_count()``)
``instruction_set`` the widest vector instruction set (:func:`instruction_set`)
``cpu_flags``       the vector features the kernels may use (:func:`cpu_flags`)
``threads``         the threads the measurement ran with
``host``            the host name
``versions``        library versions (:func:`library_versions`)
``git_commit``      evsmap's commit (:func:`evsmap.gitinfo.head_commit`, ``+dirty`` when
                    tracked files changed)
==================  =====================================================================

:func:`describe` is its first six keys (what a ``--json`` result names the machine by).
Files written before this record had other keys for some facts; :func:`read_environment` reads
them with :data:`LEGACY_KEYS` (the CPU model as ``cpu_model``, the host as ``node``, library
versions at the top level). :func:`instruction_set` names the vector instruction set the
numerical libraries pick their kernels by (and so their speed and, for int8, their rounding).

The CPU's features are read through CPUID, as the process sees them, by NumPy's run-time
dispatcher (the same detection NumPy chooses its own kernels with), not from ``/proc/cpuinfo``:
under an emulator or a hypervisor that hides features the two differ, and the libraries follow
CPUID. The two features NumPy does not report (``avx_vnni``, ``amx_int8``) come from
``/proc/cpuinfo``.
"""

from __future__ import annotations

import importlib
import os
import platform
import socket
from collections.abc import Mapping
from functools import cache
from importlib import metadata
from pathlib import Path
from typing import Any

from evsmap.fileio import renamed_keys
from evsmap.gitinfo import head_commit

VECTOR_FLAGS = ("sse4_2", "avx", "avx2", "fma", "avx512f", "avx512bw", "avx512_vnni",
                "avx_vnni", "avx512_bf16", "amx_int8", "asimd", "asimddp", "sve")
"""CPU features that pick a library's kernels, in ``/proc/cpuinfo`` spelling."""

_NUMPY_NAMES = {"SSE42": "sse4_2", "AVX": "avx", "AVX2": "avx2", "FMA3": "fma",
                "AVX512F": "avx512f", "AVX512BW": "avx512bw", "AVX512VNNI": "avx512_vnni",
                "AVX512BF16": "avx512_bf16", "ASIMD": "asimd", "ASIMDDP": "asimddp",
                "SVE": "sve"}
_PROC_ONLY = ("avx_vnni", "amx_int8")

INT8_EXACT_SETS = ("avx512-amx", "avx512-vnni", "avx2-vnni", "arm64-dotprod", "arm64-neon")
"""Instruction sets whose int8 dot products (u8 x s8) accumulate without a saturating 16-bit
step: VNNI (``VPDPBUSD``), AMX and the ARM widening or dot-product instructions. On the other
x86 sets ONNX Runtime's u8s8 kernels multiply through ``VPMADDUBSW``, whose sums of two u8 x s8
products saturate at 16 bits (see :data:`evsmap.segmenters.quantize.AUTO_SCHEMES`)."""


def cpu_model() -> str:
    """The CPU's model name (from /proc/cpuinfo on Linux), else what ``platform`` knows."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.lower().startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine() or "unknown"


def _proc_flags() -> set[str]:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith(("flags", "Features")):
                return set(line.split(":", 1)[1].split())
    except OSError:
        pass
    return set()


def _numpy_features() -> dict[str, bool] | None:
    for name in ("numpy._core._multiarray_umath", "numpy.core._multiarray_umath"):  # 2.x, 1.x
        try:
            features: dict[str, bool] = importlib.import_module(name).__cpu_features__
        except ImportError:  # pragma: no cover - NumPy 1.x
            continue
        return dict(features)
    return None  # pragma: no cover


@cache
def cpu_flags() -> tuple[str, ...]:
    """The :data:`VECTOR_FLAGS` this process can use, in that order (read once)."""
    proc = _proc_flags()
    features = _numpy_features()
    if features is None:
        present = proc
    else:
        present = {flag for name, flag in _NUMPY_NAMES.items() if features.get(name)}
        present |= proc.intersection(_PROC_ONLY)
        if "asimd" in proc:  # aarch64 kernels spell it so; NumPy's ASIMD is the same feature
            present.add("asimd")
    return tuple(f for f in VECTOR_FLAGS if f in present)


def instruction_set(flags: tuple[str, ...] | None = None) -> str:
    """The widest vector instruction set of ``flags`` (default: this machine's
    :func:`cpu_flags`) as one name: ``avx512-amx``, ``avx512-vnni``, ``avx512`` (F and BW, no
    VNNI), ``avx2-vnni``, ``avx2`` (with FMA), ``avx``, ``sse4.2``, ``arm64-dotprod``,
    ``arm64-neon``, else the architecture (``platform.machine()``)."""
    f = set(cpu_flags() if flags is None else flags)
    if {"avx512f", "avx512bw"} <= f:
        if "amx_int8" in f:
            return "avx512-amx"
        return "avx512-vnni" if "avx512_vnni" in f else "avx512"
    if {"avx2", "fma"} <= f:
        return "avx2-vnni" if "avx_vnni" in f else "avx2"
    for flag, name in (("avx", "avx"), ("sse4_2", "sse4.2"), ("asimddp", "arm64-dotprod"),
                       ("asimd", "arm64-neon")):
        if flag in f:
            return name
    return platform.machine() or "unknown"


def int8_exact(isa: str | None = None) -> bool:
    """Whether u8 x s8 products accumulate without 16-bit saturation on ``isa`` (default this
    machine's :func:`instruction_set`); see :data:`INT8_EXACT_SETS`."""
    return (isa or instruction_set()) in INT8_EXACT_SETS


def describe() -> dict[str, str | int | list[str]]:
    """Python, architecture, CPU model, core count, instruction set and vector flags: the
    machine's part of :func:`collect_environment`."""
    return {"python": platform.python_version(), "machine": platform.machine(),
            "cpu": cpu_model(), "cpus": os.cpu_count() or 0,
            "instruction_set": instruction_set(), "cpu_flags": list(cpu_flags())}


LIBRARIES = ("torch", "onnxruntime", "numpy", "fvcore")
"""The libraries whose kernels a timing depends on: always listed (``not installed`` if
absent)."""
OTHER_DISTRIBUTIONS = ("numba", "octomap-python", "open3d", "evsmap")
"""Distributions listed when installed."""


def library_versions() -> dict[str, str]:
    """The versions of :data:`LIBRARIES` (``not installed`` if absent), then of the
    :data:`OTHER_DISTRIBUTIONS` that are installed."""
    versions = {}
    for name in (*LIBRARIES, *OTHER_DISTRIBUTIONS):
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            if name in LIBRARIES:
                versions[name] = "not installed"
    return versions


def collect_environment(threads: int | None = None) -> dict[str, Any]:
    """The one record of the machine and software a measurement ran on (the keys are listed
    in the module's docstring).

    Args:
        threads: the threads the measurement runs with (default: every CPU).
    """
    return {**describe(), "threads": threads or os.cpu_count() or 1,
            "host": socket.gethostname(), "versions": library_versions(),
            "git_commit": head_commit()}


LEGACY_KEYS = {"cpu_model": "cpu", "node": "host"}
"""Keys files written before :func:`collect_environment` used for one of its facts -> its key
(and library versions were top-level keys, :data:`LIBRARIES` and ``python``-less
:func:`library_versions` names; they go into ``versions``)."""


def read_environment(stored: Mapping[str, Any]) -> dict[str, Any]:
    """A stored record of machine facts with :func:`collect_environment`'s keys: the
    :data:`LEGACY_KEYS` renamed (the new key wins where both are present) and top-level library
    versions moved into ``versions``. Other keys are kept as they are."""
    out = renamed_keys(stored, LEGACY_KEYS)
    versions = dict(out.get("versions") or {})
    for name in (*LIBRARIES, *OTHER_DISTRIBUTIONS):
        if name in out:
            versions.setdefault(name, out.pop(name))
    if versions:
        out["versions"] = versions
    return out


GPU_QUERY = ("driver_version", "clocks.sm", "clocks.max.sm", "clocks.mem", "clocks.max.mem",
             "power.limit", "pstate", "temperature.gpu")
"""What ``nvidia-smi --query-gpu`` is asked for (:func:`gpu_clocks`)."""


def gpu_clocks(index: int) -> dict[str, str]:
    """GPU ``index``'s driver, clocks (MHz, now and maximum), power limit, performance state
    and temperature, as ``nvidia-smi`` reports them now; ``{"nvidia_smi": why}`` where it
    cannot be asked."""
    import shutil
    import subprocess

    smi = shutil.which("nvidia-smi")
    if smi is None:
        return {"nvidia_smi": "not found"}
    try:
        out = subprocess.run([smi, f"--query-gpu={','.join(GPU_QUERY)}",
                              "--format=csv,noheader,nounits", "-i", str(index)],
                             capture_output=True, text=True, timeout=20, check=True).stdout
    except (OSError, subprocess.SubprocessError) as exc:
        return {"nvidia_smi": f"failed: {exc}"}
    values = [v.strip() for v in out.strip().splitlines()[0].split(",")] if out.strip() else []
    if len(values) != len(GPU_QUERY):
        return {"nvidia_smi": f"unexpected output {out.strip()!r}"}
    return {key.replace(".", "_"): value for key, value in zip(GPU_QUERY, values, strict=True)}


def collect_gpu(device: Any) -> dict[str, Any]:
    """The facts of the GPU a measurement ran on (``device`` a CUDA ``torch.device``): model,
    compute capability, memory, multiprocessors, CUDA and cuDNN versions, cuDNN autotuning and
    TF32 settings, and :func:`gpu_clocks`. The one record of them, as
    :func:`collect_environment` is of the CPU; ``{}`` for the CPU."""
    import torch

    device = torch.device(device)
    if device.type != "cuda":
        return {}
    index = device.index if device.index is not None else torch.cuda.current_device()
    props = torch.cuda.get_device_properties(index)
    return {"gpu": props.name, "gpu_index": index,
            "compute_capability": f"{props.major}.{props.minor}",
            "gpu_memory_bytes": int(props.total_memory),
            "multiprocessors": int(props.multi_processor_count),
            "cuda": torch.version.cuda, "cudnn": torch.backends.cudnn.version(),
            "cudnn_benchmark": bool(torch.backends.cudnn.benchmark),
            "tf32_matmul": bool(torch.backends.cuda.matmul.allow_tf32),
            "tf32_cudnn": bool(torch.backends.cudnn.allow_tf32),
            **gpu_clocks(index)}
