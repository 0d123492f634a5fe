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
from typing import Any

import numpy as np
import torch

from evsmap.environment import describe as describe_machine
from evsmap.fileio import atomic_write_text, read_json_object

CALIBRATION_SIZE = 384
SLOWDOWN_LIMIT = 1.4
"""A cell whose calibration ran more than this much slower than the run's best is flagged. On
the 2-core VM this was developed on, an otherwise idle machine moves the calibration by up to
25 % between cells (frequency, neighbours on the host); a CPU-bound job beside it slows it by
1.3-28x."""


def calibration_gmacs(size: int = CALIBRATION_SIZE, repeats: int = 5, bursts: int = 3,
                      gap_s: float = 0.1, warmup: int = 3) -> float:
    """G MAC/s of a ``size`` x ``size`` fp32 matmul with torch's current threads: the best of
    ``bursts`` medians of ``repeats`` products each, the bursts ``gap_s`` apart (about 0.3 s
    in all).

    A job sharing the cores slows every burst, so it shows; a blip of the host under one burst
    (a neighbour VM, a kernel thread: on the 2-core VM this was developed on they slowed a
    single 50 ms burst up to 2x on an otherwise idle machine) does not flag the cell. Within a
    burst the median, not the fastest: a job sharing the cores leaves gaps in which one
    product runs at full speed, so the fastest hides it."""
    gen = torch.Generator().manual_seed(1)
    a = torch.rand(size, size, generator=gen)
    b = torch.rand(size, size, generator=gen)
    out = torch.empty(size, size)
    for _ in range(warmup):
        torch.matmul(a, b, out=out)
    best = 0.0
    for burst in range(bursts):
        if burst:
            time.sleep(gap_s)
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            torch.matmul(a, b, out=out)
            times.append(time.perf_counter() - t0)
        best = max(best, float(size) ** 3 / float(np.median(times)) / 1e9)
    return best


OTHER_LIMIT = 0.15
"""A cell during which other processes used more than this share of all cores' time (from
``/proc/stat``) is flagged. An idle run shows 0.00-0.03; one single-threaded CPU-bound job on
the 2-core VM shows about 0.5."""


def cpu_clock() -> tuple[float, float, float] | None:
    """(wall seconds, busy CPU seconds of the whole machine, CPU seconds of this process and its
    waited-for children), or None where ``/proc/stat`` does not exist (not Linux)."""
    try:
        with open("/proc/stat") as f:
            fields = f.readline().split()
    except OSError:
        return None
    if not fields or fields[0] != "cpu":
        return None
    ticks = [int(v) for v in fields[1:9]]
    # user nice system idle iowait irq softirq steal: all but idle and iowait are busy
    busy = sum(t for i, t in enumerate(ticks) if i not in (3, 4))
    own = os.times()
    return (time.monotonic(), busy / os.sysconf("SC_CLK_TCK"),
            own.user + own.system + own.children_user + own.children_system)


MIN_SHARE_WINDOW_S = 0.5
"""Shortest window :func:`other_share` judges: ``/proc/stat`` counts CPU time in clock ticks
(10 ms), so one tick of another process's work in a 1 ms window would read as 1000 % of a core."""


def other_share(before: tuple[float, float, float] | None,
                after: tuple[float, float, float] | None, cores: int) -> float | None:
    """The share of all cores' time that processes other than this one used between two
    :func:`cpu_clock` readings (another VM's steal included): the direct measure of "other work
    shared the cores", whichever way it slows the timed code."""
    if before is None or after is None or after[0] - before[0] < MIN_SHARE_WINDOW_S:
        return None  # /proc/stat counts in clock ticks: a window of a few ticks says nothing
    others = (after[1] - before[1]) - (after[2] - before[2])
    return max(0.0, others) / ((after[0] - before[0]) * max(cores, 1))


@dataclass(frozen=True)
class Probe:
    """One look at the machine: load averages (1 and 5 min), cores, calibration G MAC/s, and
    the CPU clocks (:func:`cpu_clock`) at the start of the probe."""

    load1: float
    load5: float
    cores: int
    calibration_gmacs: float
    cpu: tuple[float, float, float] | None = None

    @classmethod
    def take(cls) -> Probe:
        clock = cpu_clock()
        load1, load5, _ = os.getloadavg()
        return cls(load1=float(load1), load5=float(load5), cores=os.cpu_count() or 1,
                   calibration_gmacs=calibration_gmacs(), cpu=clock)

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


def machine_key() -> str:
    """The calibration's machine: CPU model and torch threads (a different thread count is a
    different reference)."""
    return f"{describe_machine()['cpu']} / {torch.get_num_threads()} threads"


def machine_log_path() -> Path:
    """``$EVSMAP_CACHE_DIR/calibration.json``, else ``~/.cache/evsmap/calibration.json``: the
    best calibration each machine has shown, kept across runs."""
    from evsmap.cache import cache_root

    return cache_root() / "calibration.json"


class CalibrationLog:
    """The best calibration seen, kept in small JSON files so that cells timed in separate
    processes - and runs on the same machine - compare against the same reference: the best of
    this run (``path``) and the best this machine has shown in any run (``machine_path``). A run
    that is loaded from its start is thus still compared with the machine idle.

    Args:
        path: the run's JSON file (created on first use); None keeps the best in memory only.
        machine_path: the machine-wide file (:func:`machine_log_path`); None: none.
    """

    def __init__(self, path: str | os.PathLike[str] | None = None,
                 machine_path: str | os.PathLike[str] | None = None) -> None:
        self.path = None if path is None else Path(path)
        self.machine_path = None if machine_path is None else Path(machine_path)
        self._best = 0.0

    def best(self, seen: float) -> float:
        """Record ``seen`` G MAC/s; returns the reference: the best of the run so far
        (``seen`` included) or of this machine, whichever is higher."""
        best = max(self._best, seen)
        if self.path is not None:
            best = max(best, read_json_object(self.path).get("best_gmacs", 0.0))
            _write(self.path, {"best_gmacs": best})
        self._best = best
        if self.machine_path is not None:
            table = read_json_object(self.machine_path)
            key = machine_key()
            machine = max(float(table.get(key, 0.0)), best)
            table[key] = machine
            _write(self.machine_path, table)
            best = machine
        return best



def _write(path: Path, data: dict[str, Any]) -> None:
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(path, json.dumps(data))
    except OSError:
        pass  # a read-only cache: the reference stays in memory


def contention(before: Probe, after: Probe,
               log: CalibrationLog | None = None) -> dict[str, Any]:
    """What the two probes around a timed cell say: the slowdown of its slower calibration
    against the run's best, the share of the cores other processes used in between
    (``other_share``), the load, and ``contended`` when the slowdown passes
    :data:`SLOWDOWN_LIMIT` or the share :data:`OTHER_LIMIT`. ``severity``: the larger of the
    two against its limit (above 1: contended), to pick the calmer of two tries."""
    log = log or CalibrationLog()
    slowest = min(before.calibration_gmacs, after.calibration_gmacs)
    best = log.best(max(before.calibration_gmacs, after.calibration_gmacs))
    slowdown = best / slowest if slowest > 0 else float("inf")
    share = other_share(before.cpu, after.cpu, before.cores)
    severity = max(slowdown / SLOWDOWN_LIMIT, 0.0 if share is None else share / OTHER_LIMIT)
    return {"before": before.as_dict(), "after": after.as_dict(), "slowdown": slowdown,
            "other_share": share, "severity": severity, "contended": bool(severity > 1.0)}


def retry_can_help(machine: dict[str, Any]) -> bool:
    """Whether timing a contended cell again, after a pause, can give a calmer figure: when
    other processes of this machine used the cores (:data:`OTHER_LIMIT`: work that may end),
    or when that share is unknown. A slowdown with the cores otherwise idle is the host's (a
    neighbour VM, a frequency step): it is flagged, and a second try costs the cell's time
    again for nothing it can remove (a cold ``--quick`` run here retried a 15 s mapping run
    whose calibration ran 1.9x slow with 0 % of the cores used by others)."""
    share = machine.get("other_share")
    return share is None or float(share) > OTHER_LIMIT


HOST_SLOWDOWN_NOTE = ("not timed again: no other process used the cores, so the slowdown was "
                      "the host's, which a pause does not remove")
"""The note of a contended cell :func:`retry_can_help` did not time again."""


def severity(machine: dict[str, Any]) -> float:
    """:func:`contention`'s ``severity`` (records written before it: slowdown / limit)."""
    if machine.get("severity") is not None:
        return float(machine["severity"])
    return float(machine["slowdown"]) / SLOWDOWN_LIMIT


def describe(machine: dict[str, Any]) -> str:
    """One phrase for a contended cell: what the probes saw."""
    parts = [f"the calibration matmul ran {machine['slowdown']:.2f}x slower than the run's best"]
    if machine.get("other_share") is not None:
        parts.append(f"other processes used {100 * machine['other_share']:.0f} % of the cores")
    before = machine.get("before") or {}
    load = (f" (load {before['load1']:.1f} on {before['cores']} cores)"
            if "load1" in before and "cores" in before else "")
    return "contended: " + "; ".join(parts) + load
