"""Where a run's wall time goes: every second of ``evsmap reproduce`` in a named phase.

Two levels, both plain data (the report formats them, ``index.md``'s "Where the time went"):

* **the run's phases** (:class:`RunClock`, stored in ``run.json`` as ``time_accounting``): the
  process's start-up (interpreter and imports, until the run begins), the plan, the estimate's
  calibration, the cells that cannot run here, the executor's start, the untimed cells' pool,
  the timed cells, the mapping runs, Table IV's cells read from them, the extra passes
  (``--train``, ``--precision int8``), ``run.json``; the difference between their sum and the
  wall clock is stated as unaccounted;
* **the time around each timed cell** (a record's ``around``, :func:`settle_around`): a timed
  cell runs alone in a fresh interpreter, so the driver's wait for it is the process's spawn
  and imports (``start_s``), the worker's setup before the cell (``setup_s``: the run's
  context, the table's cell), the cell itself (``cell_s``, the record's ``seconds``: its
  exports, calibration probes, warm-up, timed passes, and a speed cell's second try), what
  follows it in the worker (``finish_s``: memory, environment), the record's way back and the
  process's end (``return_s``), and another try of the whole process with its pause
  (``retry_s``: a mapping run timed twice on a busy machine); an untimed cell's is its share of
  its pool's time (:func:`pooled_around`).

The worker's instants are wall-clock stamps (``time.time``: one clock for every process of this
machine); the driver's spans use the same clock.
"""

from __future__ import annotations

import contextlib
import os
import time
from collections.abc import Iterator
from typing import Any

PHASES = ("start-up", "plan", "estimate", "n/a cells", "executor", "untimed cells",
          "timed cells", "labels check", "mapping runs", "Table IV read", "extra passes",
          "run.json")
"""The run's phases, in the order they happen (a phase may occur in two groups: the claims'
cells first, then the others; its times add)."""
AROUND = ("start_s", "setup_s", "cell_s", "finish_s", "return_s", "retry_s")
"""The parts of the driver's wait for a timed cell (:func:`settle_around`), in order."""
STAMPS = ("entered", "began", "left")
"""The worker's wall-clock instants a record carries until the driver turns them into spans:
the worker function entered, the cell began, the worker function left."""


def stamp() -> float:
    """Now, on the clock every process of this machine shares."""
    return time.time()


def process_age_s() -> float | None:
    """Seconds since this process started (the interpreter's start-up and imports count),
    from ``/proc``; None where there is none."""
    try:
        with open("/proc/self/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
        with open("/proc/uptime") as f:
            uptime = float(f.read().split()[0])
        ticks = os.sysconf("SC_CLK_TCK")
        return max(0.0, uptime - int(fields[19]) / ticks)
    except (OSError, ValueError, IndexError):
        return None


class RunClock:
    """The run's phases (module docstring): ``with clock.phase(name): ...`` adds the block's
    wall time to ``name``; :meth:`as_dict` is ``run.json``'s ``time_accounting``."""

    def __init__(self) -> None:
        self.begun = stamp()
        self.seconds: dict[str, float] = {}
        self.estimate_s: float | None = None
        """The start line's estimate of the run (:mod:`evsmap.runner.estimate`), kept beside
        the wall time so that a run says how well it was estimated."""

    def add(self, name: str, seconds: float) -> None:
        if name not in PHASES:
            raise ValueError(f"unknown run phase {name!r} (known: {', '.join(PHASES)})")
        self.seconds[name] = self.seconds.get(name, 0.0) + max(0.0, seconds)

    @contextlib.contextmanager
    def phase(self, name: str) -> Iterator[None]:
        t0 = stamp()
        try:
            yield
        finally:
            self.add(name, stamp() - t0)

    def as_dict(self) -> dict[str, Any]:
        """The phases in order, the wall time from the process's start (start-up included),
        and what no phase holds."""
        wall = stamp() - self.begun + self.seconds.get("start-up", 0.0)
        phases = {name: round(self.seconds[name], 3) for name in PHASES if name in self.seconds}
        out: dict[str, Any] = {"wall_s": round(wall, 3), "phases": phases,
                               "unaccounted_s": round(wall - sum(self.seconds.values()), 3)}
        if self.estimate_s is not None:
            out["estimate_s"] = round(self.estimate_s, 1)
        return out


def phase(clock: RunClock | None, name: str) -> contextlib.AbstractContextManager[None]:
    """``clock.phase(name)``, or nothing without a clock."""
    return clock.phase(name) if clock is not None else contextlib.nullcontext()


def settle_around(around: dict[str, float], seconds: float, submitted: float,
                  received: float, first_submitted: float | None = None) -> dict[str, float]:
    """The spans of a timed cell's ``around`` (module docstring) from the worker's stamps
    (:data:`STAMPS`) and the driver's: ``submitted`` (this try's process asked for),
    ``received`` (its record back), ``first_submitted`` (the first try's, when it ran more
    than once). Without the worker's stamps (an executor on another machine), only the
    driver's wait and the cell."""
    first = submitted if first_submitted is None else first_submitted
    out = {"wall_s": received - first, "cell_s": seconds, "retry_s": submitted - first}
    if all(k in around for k in STAMPS):
        entered, began, left = (around[k] for k in STAMPS)
        out.update(start_s=entered - submitted, setup_s=began - entered,
                   finish_s=left - began - seconds, return_s=received - left)
    return {k: round(max(0.0, v), 4) for k, v in out.items()}


def worker_stamps(entered: float, began: float) -> dict[str, float]:
    """The stamps a worker puts in its record's ``around`` as it returns."""
    return {"entered": entered, "began": began, "left": stamp()}


def pooled_around(seconds: float, workers: int) -> dict[str, float]:
    """An untimed cell's ``around``: its share of the pool's wall time (its own seconds over
    the pool's ``workers``, which run side by side; 0 for a record copied from an equal
    configuration's), marked ``pooled`` (its parts are the pool's phase, not its own)."""
    return {"wall_s": round(max(0.0, seconds) / max(1, int(workers)), 4), "pooled": 1.0}
