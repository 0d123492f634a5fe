"""Measured memory: the resident set size (RSS) of this process and its peak over a run.

``tracemalloc`` sees numpy's allocations but not torch's CPU tensors nor the C++ octrees of
OctoMap, so memory is read from the kernel instead: the current RSS (``psutil``) and the peak
(``VmHWM`` in ``/proc/self/status``, else ``getrusage``'s ``ru_maxrss``). On Linux the peak can
be reset (``5`` written to ``/proc/self/clear_refs``, Linux 4.0 and later), so the peak of one
run is measured from where that run started rather than from the interpreter's start.
"""

from __future__ import annotations

import gc
import resource
import sys
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

_STATUS = Path("/proc/self/status")
_CLEAR_REFS = Path("/proc/self/clear_refs")


def current_rss() -> int:
    """This process's resident set size now, bytes."""
    import psutil

    return int(psutil.Process().memory_info().rss)


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


def reset_peak() -> bool:
    """Reset the peak RSS to the current RSS; False where the kernel does not allow it."""
    try:
        _CLEAR_REFS.write_text("5")
    except OSError:
        return False
    return True


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
