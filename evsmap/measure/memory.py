"""Measured memory: the resident set size (RSS) of this process and its peak over a run.

``tracemalloc`` sees numpy's allocations but not torch's CPU tensors nor the C++ octrees of
OctoMap, so memory is read from the kernel instead: the current RSS (``psutil``) and the peak
(``VmHWM`` in ``/proc/self/status``, else ``getrusage``'s ``ru_maxrss``). On Linux the peak can
be reset (``5`` written to ``/proc/self/clear_refs``, Linux 4.0 and later), so the peak of one
run is measured from where that run started rather than from the interpreter's start.

glibc's allocator keeps freed blocks for reuse, and by default it decides at run time which
blocks it maps separately (and unmaps on free) and which it carves from its heap: its *dynamic
mmap threshold* rises to the size of the largest mapped block freed so far. The same code can
then end with different RSS peaks (20-30 % apart, measured on the gate's mapping workload),
depending on the order of its frees. :func:`fixed_mmap_threshold` turns that off, so a peak is
the memory the code held, reproducibly; :func:`trim_heap` returns free heap pages.

The RSS also counts the pages of shared libraries and other mapped files, and how many of those
a first use maps depends on the kernel's page cache rather than on the code: importing
``llvmlite`` (numba's compiler, a 170 MiB library) added 37 MiB of file pages in a virtual
environment installed a day earlier and 94 MiB in one installed a minute earlier, the same file
and the same import (the page cache held the fresh copy in large folios, each mapped whole on
the first fault). :func:`resident_parts` splits the RSS into its anonymous, file and shared
parts (``RssAnon``, ``RssFile``, ``RssShmem``, Linux 4.5 and later), so a measurement can leave
the file part out.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import gc
import resource
import sys
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

_STATUS = Path("/proc/self/status")
_CLEAR_REFS = Path("/proc/self/clear_refs")
_M_MMAP_THRESHOLD = -3  # mallopt parameter numbers, glibc's malloc.h
_M_TRIM_THRESHOLD = -1
MMAP_THRESHOLD_MIN = 128 * 1024  # glibc's initial threshold: blocks above it are mapped
MMAP_THRESHOLD_MAX = 32 * 1024 * 1024  # where glibc's dynamic threshold stops rising (64-bit)


def _libc() -> Any:
    name = ctypes.util.find_library("c")
    if not name:
        return None
    try:
        lib = ctypes.CDLL(name)
    except OSError:
        return None
    return lib if hasattr(lib, "mallopt") else None  # glibc; musl and macOS have no mallopt


def fixed_mmap_threshold(nbytes: int) -> bool:
    """Fix glibc's mmap threshold at ``nbytes`` (and its trim threshold at twice that), which
    also stops its dynamic adjustment; False where the C library is not glibc."""
    lib = _libc()
    if lib is None:
        return False
    return bool(lib.mallopt(_M_MMAP_THRESHOLD, int(nbytes))
                and lib.mallopt(_M_TRIM_THRESHOLD, 2 * int(nbytes)))


def trim_heap() -> None:
    """Give free heap pages back to the system (glibc's ``malloc_trim``), so the RSS that
    follows is the live data; nothing elsewhere."""
    lib = _libc()
    if lib is not None:
        lib.malloc_trim(0)


def current_rss() -> int:
    """This process's resident set size now, bytes."""
    import psutil

    return int(psutil.Process().memory_info().rss)


def resident_parts() -> dict[str, int] | None:
    """This process's RSS by kind, bytes: ``{"anon", "file", "shmem"}`` (the private memory it
    allocated, the pages of mapped files and shared libraries, shared memory); None where the
    kernel does not say (not Linux, or Linux before 4.5)."""
    keys = {"RssAnon:": "anon", "RssFile:": "file", "RssShmem:": "shmem"}
    parts: dict[str, int] = {}
    try:
        for line in _STATUS.read_text().splitlines():
            key = line.split(":", 1)[0] + ":"
            if key in keys:
                parts[keys[key]] = int(line.split()[1]) * 1024
    except OSError:
        return None
    return parts if len(parts) == len(keys) else None


def peak_rss() -> int:
    """This process's peak resident set size, bytes: since the last :func:`reset_peak`, or
    since the process started where the peak cannot be reset."""
    try:
        for line in _STATUS.read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) * 1024
    except OSError:
        pass
    maxrss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return int(maxrss if sys.platform == "darwin" else maxrss * 1024)  # macOS: bytes; Linux: KiB


_reached_before_reset = 0
"""The highest peak read just before a reset since :func:`mark_peak` (bytes)."""


def reset_peak() -> bool:
    """Reset the peak RSS to the current RSS; False where the kernel does not allow it. The
    peak reached so far is remembered for :func:`peak_since_mark`."""
    global _reached_before_reset
    _reached_before_reset = max(_reached_before_reset, peak_rss())
    return _clear_peak()


def _clear_peak() -> bool:
    try:
        _CLEAR_REFS.write_text("5")
    except OSError:
        return False
    return True


def mark_peak() -> None:
    """Start a new span for :func:`peak_since_mark` (a cell of a run): the peak is reset and
    what earlier spans reached forgotten."""
    global _reached_before_reset
    _reached_before_reset = 0
    _clear_peak()


def peak_since_mark() -> int:
    """The process's peak RSS since the last :func:`mark_peak`, bytes, across any
    :func:`reset_peak` in between (a measurement of its own inside the span)."""
    return max(_reached_before_reset, peak_rss())


@dataclass
class PeakMemory:
    """The memory a block of code took: ``with PeakMemory() as m: ...``.

    Attributes:
        start_rss_bytes: RSS when the block began (after a garbage collection).
        peak_rss_bytes: the process's peak RSS while the block ran (from the block's start when
            ``scope`` is ``"block"``; from the process's start when it is ``"process"``, on a
            system where the peak cannot be reset).
        scope: ``"block"`` or ``"process"``.
    """

    start_rss_bytes: int = 0
    peak_rss_bytes: int = 0
    scope: str = "block"

    @property
    def added_bytes(self) -> int:
        """``peak_rss_bytes - start_rss_bytes``: the most the block held above its start."""
        return max(0, self.peak_rss_bytes - self.start_rss_bytes)

    def __enter__(self) -> PeakMemory:
        gc.collect()
        self.scope = "block" if reset_peak() else "process"
        self.start_rss_bytes = current_rss()
        return self

    def __exit__(self, *exc: object) -> None:
        self.peak_rss_bytes = max(peak_rss(), current_rss())

    def as_dict(self) -> dict[str, Any]:
        return {**asdict(self), "added_bytes": self.added_bytes}
