"""How busy the machine is while something is timed, so that a figure taken under contention
says so.

Two signals:

* the load average (``os.getloadavg``) against the number of cores - what else the operating
  system is running, smoothed over a minute;
* a calibration: a small fp32 matmul timed a few times (:func:`calibration_gmacs`), before and
  after a timed cell. Another job on the same cores slows it down at once, so the slowest of the
  two against the best seen in the whole run (:class:`CalibrationLog`) is the cell's
  ``slowdown``.
"""

from __future__ import annotations

import json
import os
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch

CALIBRATION_SIZE = 384
SLOWDOWN_LIMIT = 1.4
"""A cell whose calibration ran more than this much slower than the run's best is flagged. On
the 2-core VM this was developed on, an otherwise idle machine moves the calibration by up to
25 % between cells (frequency, neighbours on the host); a CPU-bound job beside it slows it by
1.3-28x."""


def calibration_gmacs(size: int = CALIBRATION_SIZE, repeats: int = 15, warmup: int = 3) -> float:
    """G MAC/s of a ``size`` x ``size`` fp32 matmul with torch's current threads: the fastest of
    ``repeats`` products after ``warmup`` (about 50 ms in all). The fastest, not the median:
    a brief interruption does not move it (5 % spread over repeated calls on an idle 2-core
    machine), a job holding the cores does."""
    gen = torch.Generator().manual_seed(1)
    a = torch.rand(size, size, generator=gen)
    b = torch.rand(size, size, generator=gen)
    out = torch.empty(size, size)
    for _ in range(warmup):
        torch.matmul(a, b, out=out)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        torch.matmul(a, b, out=out)
        times.append(time.perf_counter() - t0)
    return float(size) ** 3 / float(np.min(times)) / 1e9


@dataclass(frozen=True)
class Probe:
    """One look at the machine: load averages (1 and 5 min), cores, calibration G MAC/s."""

    load1: float
    load5: float
    cores: int
    calibration_gmacs: float

    @classmethod
    def take(cls) -> Probe:
        load1, load5, _ = os.getloadavg()
        return cls(load1=float(load1), load5=float(load5), cores=os.cpu_count() or 1,
                   calibration_gmacs=calibration_gmacs())

    def as_dict(self) -> dict:
        return asdict(self)


class CalibrationLog:
    """The best calibration of a run, kept in a small JSON file in the run folder so that cells
    timed in separate processes compare against the same reference.

    Args:
        path: the JSON file (created on first use); None keeps the best in memory only.
    """

    def __init__(self, path: str | os.PathLike[str] | None = None) -> None:
        self.path = None if path is None else Path(path)
        self._best = 0.0

    def best(self, seen: float) -> float:
        """Record ``seen`` G MAC/s; returns the best of the run so far (``seen`` included)."""
        best = max(self._best, seen)
        if self.path is not None:
            try:
                best = max(best, float(json.loads(self.path.read_text())["best_gmacs"]))
            except (OSError, ValueError, KeyError, TypeError):
                pass
            self.path.parent.mkdir(parents=True, exist_ok=True)
            tmp = self.path.with_suffix(".tmp")
            tmp.write_text(json.dumps({"best_gmacs": best}))
            os.replace(tmp, self.path)
        self._best = best
        return best


def contention(before: Probe, after: Probe, log: CalibrationLog | None = None) -> dict:
    """What the two probes around a timed cell say: the slowdown of its slower calibration
    against the run's best, the load, and ``contended`` when the slowdown passes
    :data:`SLOWDOWN_LIMIT`."""
    log = log or CalibrationLog()
    slowest = min(before.calibration_gmacs, after.calibration_gmacs)
    best = log.best(max(before.calibration_gmacs, after.calibration_gmacs))
    slowdown = best / slowest if slowest > 0 else float("inf")
    return {"before": before.as_dict(), "after": after.as_dict(), "slowdown": slowdown,
            "contended": bool(slowdown > SLOWDOWN_LIMIT)}
