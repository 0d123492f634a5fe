"""How long a run's cells will take on this machine, before and while it runs.

Each cell's estimate comes from the best source at hand:

1. ``history``: how long the same cell took here before (``<cache>/durations.json``, per
   machine: CPU model, instruction set and threads), written as cells finish;
2. ``reference``: how long it took on the machine that made
   ``evsmap/runner/reference_durations.json`` (a first run with an empty cache, exports
   included), scaled by the two machines' calibration matmuls
   (:func:`evsmap.measure.contention.calibration_gmacs`);
3. ``default``: a figure per kind of cell, for cells neither knows (a plug-in's, a new row).

A cell's duration is what the run spends on it (:func:`cell_duration`): for a timed cell the
driver's whole wait (its fresh process's start-up and imports, its retries:
:mod:`evsmap.runner.accounting`), for an untimed one its own time. What a run spends outside
its cells (the start-up, the plan, the estimate's calibration, the pools' start, ``run.json``)
comes from the same sources (:data:`OUTSIDE_KEY`: this machine's last run, else the reference's
scaled), shared out over the cells pending, so the start line's estimate is the run's, not its
cells'.

A first run in a cache pays once for what later runs find cached (ONNX exports, FLOP counts,
ground truths, compiled kernels, the calibration): its durations are kept apart in the history
(:data:`FIRST_KEY`). A first run (this machine's history is empty: a new cache) is estimated from
the reference's first run; a later one from this machine's later runs, else from its first run
scaled by the reference's later-over-first ratio of that cell (:data:`REFERENCE_FILES`' ``warm``
section: a second run on the reference machine, same cache), else from the reference's later run.

While the run goes, the estimates of the cells left are scaled by how the finished ones compared
with theirs (:meth:`Estimator.remaining_s`), so the time left a person sees corrects itself.
"""

from __future__ import annotations

import json
import time
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from evsmap.fileio import atomic_write_text, read_json_object

REFERENCE_FILES = {False: Path(__file__).with_name("reference_durations.json"),
                   True: Path(__file__).with_name("reference_durations_quick.json")}
"""The shipped durations of a first full run and of a first ``--quick`` run, each on an empty
cache (``benchmarks/reference_durations.py`` writes them)."""
DURATIONS_FILE = "durations.json"
DEFAULT_S = {"complexity": 10.0, "speed": 30.0, "accuracy": 120.0, "mapping": 60.0}
"""Seconds assumed for a cell of each kind that neither the history nor the reference knows."""
CORRECTION_LIMITS = (0.5, 3.0)
"""The running correction of the estimates left is kept within these factors."""
OUTSIDE_KEY = "(outside cells)"
"""The history's and the reference's entry for a whole run's time outside its cells, with the
count of cells it was spread over (``cells``)."""
FIRST_KEY = "(first run)"
"""The history's entry for the durations learnt on this machine's first run in its cache (cold:
exports, counts and compiles included), kept apart from later runs' (warm)."""
CORRECTION_PRIOR_S = 60.0
"""Seconds of "as estimated" the correction starts from, so that the first short cells (whose
time is mostly a process's start-up: 8 s for a 2 s cell) do not triple the time left."""


def machine_id(threads: int, *, quick: bool = False) -> str:
    """The history's machine: CPU model, instruction set and threads (a ``--quick`` run's cells
    are kept apart: same keys, smaller work)."""
    from evsmap.environment import describe

    machine = describe()
    return (f"{machine['cpu']} / {machine['instruction_set']} / {threads} threads"
            + (" / quick" if quick else ""))


@dataclass
class Estimator:
    """Seconds per cell (module docstring).

    Attributes:
        history: this machine's earlier durations, by cell key.
        reference: the reference machine's durations, by cell key.
        scale: the reference machine's calibration over this one's (a slower machine: > 1).
        path: where the history is kept (None: not kept).
        machine: this machine's key in the history file.
        outside: a whole run's seconds outside its cells and the count of cells it measured
            (this machine's last run, else the reference's scaled; None: unknown).
        first: this is the first run in this cache (no history here): estimated and learnt as
            a first run.
        history_first: this machine's first run's durations, by cell key.
        reference_warm: the reference machine's second run's durations, by cell key.
    """

    history: dict[str, float] = field(default_factory=dict)
    reference: dict[str, float] = field(default_factory=dict)
    scale: float = 1.0
    path: Path | None = None
    machine: str = ""
    outside: tuple[float, int] | None = None
    first: bool = False
    history_first: dict[str, float] = field(default_factory=dict)
    reference_warm: dict[str, float] = field(default_factory=dict)
    _estimated: float = 0.0
    _taken: float = 0.0

    @classmethod
    def load(cls, *, threads: int, calibration_gmacs: float | None,
             cache_root: Path | None = None, quick: bool = False) -> Estimator:
        """The estimator of this machine: its history under ``cache_root`` (default: evsmap's
        cache) and the shipped reference scaled by ``calibration_gmacs`` (None: unscaled);
        ``quick``: a ``--quick`` run's (its own history and reference; a reference of the
        other kind is not used)."""
        from evsmap.cache import cache_root as default_root

        root = cache_root if cache_root is not None else default_root()
        path = root / DURATIONS_FILE
        machine = machine_id(threads, quick=quick)
        history = dict(read_json_object(path).get(machine, {}))
        first_run = history.pop(FIRST_KEY, None)
        first_run = dict(first_run) if isinstance(first_run, dict) else {}
        reference_data = read_json_object(REFERENCE_FILES[quick])
        same_kind = bool((reference_data.get("run") or {}).get("quick")) == quick
        warm_data = (reference_data.get("warm") or {}) if same_kind else {}
        ref_cal = (reference_data.get("machine") or {}).get("calibration_gmacs")
        scale = ref_cal / calibration_gmacs if ref_cal and calibration_gmacs else 1.0
        first = not history and not first_run
        outside = _outside_estimate(
            first=first, scale=scale, later=history.pop(OUTSIDE_KEY, None),
            first_run=first_run.pop(OUTSIDE_KEY, None),
            reference=reference_data.get("outside") if same_kind else None,
            reference_warm=warm_data.get("outside"))
        return cls(history=_seconds(history), history_first=_seconds(first_run),
                   reference=_seconds(reference_data.get("cells", {}) if same_kind else {}),
                   reference_warm=_seconds(warm_data.get("cells", {})), scale=scale,
                   path=path, machine=machine, outside=outside, first=first)

    def seconds(self, key: str, kind: str) -> tuple[float, str]:
        """``(seconds, source)`` for the cell ``key`` of ``kind`` (source: ``history``,
        ``history (first run)`` (within it), ``history (first run, scaled)``, ``reference`` or
        ``default``; module docstring)."""
        if self.first and key in self.history_first:
            return self.history_first[key], "history (first run)"
        if not self.first:
            if key in self.history:
                return self.history[key], "history"
            if key in self.history_first:
                cold, warm = self.reference.get(key), self.reference_warm.get(key)
                ratio = warm / cold if cold and warm else 1.0
                return self.history_first[key] * ratio, "history (first run, scaled)"
            if key in self.reference_warm:
                return self.reference_warm[key] * self.scale, "reference"
        if key in self.reference:
            return self.reference[key] * self.scale, "reference"
        return DEFAULT_S.get(kind, 30.0), "default"

    def total_s(self, items: Iterable[tuple[str, str]]) -> float:
        """The sum of the estimates of ``(key, kind)`` items."""
        return sum(self.seconds(key, kind)[0] for key, kind in items)

    def outside_s(self, cells: int) -> float:
        """The time outside the cells of a run measuring ``cells`` cells: the known run's,
        shared out per cell (all of it for a run at least as large)."""
        if self.outside is None or cells <= 0:
            return 0.0
        seconds, count = self.outside
        return seconds * min(1.0, cells / max(count, 1))

    def run_s(self, items: Iterable[tuple[str, str]]) -> float:
        """A run's estimate: its cells' and its time outside them."""
        items = list(items)
        return self.total_s(items) + self.outside_s(len(items))

    def learn_outside(self, seconds: float, cells: int) -> None:
        """A run on this machine spent ``seconds`` outside its ``cells`` cells: kept in the
        history for the next run's estimate."""
        if cells > 0 and seconds >= 0:
            self.outside = (float(seconds), int(cells))
            entry = {"seconds": round(float(seconds), 2), "cells": int(cells)}
            if self.first:
                self._store(FIRST_KEY, {**self.history_first, OUTSIDE_KEY: entry})
            else:
                self._store(OUTSIDE_KEY, entry)

    def sources(self, items: Iterable[tuple[str, str]]) -> dict[str, int]:
        """How many of the items each source estimates."""
        counts: dict[str, int] = {}
        for key, kind in items:
            source = self.seconds(key, kind)[1]
            counts[source] = counts.get(source, 0) + 1
        return counts

    def learn(self, key: str, kind: str, seconds: float) -> None:
        """A cell finished in ``seconds``: fold it into the running correction and keep it in
        the history (written at once: an interrupted run keeps what it learnt)."""
        if seconds <= 0:
            return
        self._estimated += self.seconds(key, kind)[0]
        self._taken += seconds
        if self.first:
            self.history_first[key] = round(float(seconds), 2)
            self._store(FIRST_KEY, dict(self.history_first))
        else:
            self.history[key] = float(seconds)
            self._store(key, round(float(seconds), 2))

    def _store(self, key: str, value: Any) -> None:
        """``key``'s entry of this machine in the history file (at once: an interrupted run
        keeps what it learnt)."""
        if self.path is None:
            return
        data = read_json_object(self.path)
        data[self.machine] = {**data.get(self.machine, {}), key: value}
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            atomic_write_text(self.path, json.dumps(data, indent=0, sort_keys=True))
        except OSError:
            pass  # a read-only cache: the estimate stays in memory

    def correction(self) -> float:
        """Time taken over time estimated for the cells finished so far, each side starting
        from :data:`CORRECTION_PRIOR_S` (1 before any cell, and near 1 while little is done)."""
        if self._estimated <= 0:
            return 1.0
        low, high = CORRECTION_LIMITS
        ratio = (self._taken + CORRECTION_PRIOR_S) / (self._estimated + CORRECTION_PRIOR_S)
        return min(high, max(low, ratio))

    def remaining_s(self, items: Iterable[tuple[str, str]]) -> float:
        """The estimate of the cells left, corrected by how the finished ones went, and their
        share of the time outside cells."""
        items = list(items)
        return self.total_s(items) * self.correction() + self.outside_s(len(items))


def cell_duration(record: Any) -> float:
    """What a run spent on a cell (:class:`~evsmap.runner.records.CellRecord`): the driver's
    whole wait for a timed cell (``around["wall_s"]``), else the cell's own seconds."""
    around = record.around or {}
    return float(around.get("wall_s", record.seconds))


def _seconds(entries: Any) -> dict[str, float]:
    """The cell entries of a history or reference as seconds (other entries left out)."""
    if not isinstance(entries, dict):
        return {}
    return {k: float(v) for k, v in entries.items() if isinstance(v, (int, float))}


def _outside_estimate(*, first: bool, scale: float, later: Any, first_run: Any, reference: Any,
                      reference_warm: Any) -> tuple[float, int] | None:
    """A run's time outside its cells: a first run's from the reference's first run (scaled);
    a later run's from this machine's later run, else its first run's scaled by the reference's
    later-over-first ratio, else the reference's later run (scaled)."""
    ref_cold, ref_warm = _outside(reference, scale), _outside(reference_warm, scale)
    if first:
        return ref_cold
    if (known := _outside(later, 1.0)) is not None:
        return known
    if (cold := _outside(first_run, 1.0)) is not None:
        ratio = ref_warm[0] / ref_cold[0] if ref_cold and ref_warm and ref_cold[0] > 0 else 1.0
        return cold[0] * ratio, cold[1]
    return ref_warm or ref_cold


def _outside(entry: Any, scale: float) -> tuple[float, int] | None:
    """``(seconds, cells)`` of a stored time outside cells (scaled), or None."""
    if not isinstance(entry, dict):
        return None
    try:
        return float(entry["seconds"]) * scale, int(entry["cells"])
    except (KeyError, TypeError, ValueError):
        return None


@dataclass
class Budget:
    """``--budget``: the run's time, from its start; a cell whose estimate does not fit in the
    time left is not started (recorded as not measured, with the reason)."""

    minutes: float
    start: float = field(default_factory=time.monotonic)

    def left_s(self) -> float:
        return self.minutes * 60.0 - (time.monotonic() - self.start)

    def refuses(self, estimate_s: float) -> str | None:
        """Why a cell estimated at ``estimate_s`` is left out, or None when it fits."""
        left = self.left_s()
        if estimate_s <= left:
            return None
        return (f"n/a - left out by --budget {self.minutes:g} (estimated {estimate_s:.0f} s, "
                f"{max(left, 0.0):.0f} s of the budget left); run it with a larger --budget or "
                f"`--resume`")


def format_duration(seconds: float) -> str:
    """``"45 s"``, ``"12 min"``, ``"1 h 05 min"``."""
    if seconds < 90:
        return f"{seconds:.0f} s"
    minutes = round(seconds / 60.0)
    if minutes < 60:
        return f"{minutes} min"
    return f"{minutes // 60} h {minutes % 60:02d} min"

