"""How long a speed measurement runs: until its median is known well enough, or its time is up.

One rule for every row of a table (:class:`TimingPolicy`): untimed warm-up passes (at least
``warmup`` and at least ``warmup_s`` seconds of them), then timed passes one at a time until

* the median's confidence interval is tight enough: the half-width of its ``confidence``
  interval (percentile bootstrap over the passes, seeded, so the same times give the same
  interval) is at most ``target_rel_ci`` of the median - stopped on ``"precision"``;
* or ``budget_s`` seconds of timed passes are spent - stopped on ``"budget"``, the precision
  reached is kept and stated;
* or ``max_runs`` passes are timed - stopped on ``"max_runs"``;

never before ``min_runs`` timed passes. A fast network reaches the target in a second or two; a
slow one (several seconds a pass) stops on its budget after its floor of passes, with the
precision those passes give. Each record keeps the interval, the precision and why it stopped
(:class:`TimedPasses`), so a report can print how far each figure can be trusted.
"""

from __future__ import annotations

import functools
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

STOP_REASONS = ("precision", "budget", "max_runs")


@dataclass(frozen=True)
class TimingPolicy:
    """When a speed measurement stops (module docstring).

    Attributes:
        target_rel_ci: stop once the median's CI half-width is at most this share of it.
        confidence: the interval's confidence level.
        min_runs: timed passes before any stop.
        budget_s: seconds of timed passes after which the measurement stops (once
            ``min_runs`` are done), whatever precision it reached.
        max_runs: timed passes at most.
        warmup, warmup_s: untimed passes first: at least ``warmup`` of them and at least
            ``warmup_s`` seconds (at most ``max_warmup``). Two, not one: at 2048x1024 the pass
            after a single warm-up one still ran 25-60 % slow in ONNX Runtime (ESANet-R34
            3.94 s then 2.99 s; SSMA 12.5 s then 9.6 s; DCNN-R152 at 640x480 8.1 s then 5.6 s),
            and with a floor of 3 passes that one pass made a slow network's interval +-30 %.
        max_warmup: untimed passes at most.
        resamples: bootstrap resamples of the median.
    """

    target_rel_ci: float = 0.03
    confidence: float = 0.95
    min_runs: int = 3
    budget_s: float = 10.0
    max_runs: int = 1000
    warmup: int = 2
    warmup_s: float = 1.0
    max_warmup: int = 20
    resamples: int = 2000

    def __post_init__(self) -> None:
        if not 0 < self.target_rel_ci < 1 or not 0.5 <= self.confidence < 1:
            raise ValueError("target_rel_ci must be in (0, 1) and confidence in [0.5, 1)")
        if self.min_runs < 3 or self.max_runs < self.min_runs or self.budget_s <= 0:
            raise ValueError("need min_runs >= 3, max_runs >= min_runs and budget_s > 0")
        if self.warmup < 0 or self.max_warmup < self.warmup or self.warmup_s < 0:
            raise ValueError("need 0 <= warmup <= max_warmup and warmup_s >= 0")

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)

    def describe(self) -> str:
        """The rule in one line, for notes and the report."""
        return (f"timed until the median's {self.confidence:.0%} CI is within "
                f"+-{self.target_rel_ci:.0%} ({self.min_runs} to {self.max_runs} passes, "
                f"{self.budget_s:g} s budget, after >= {self.warmup} warm-up passes and "
                f">= {self.warmup_s:g} s)")


@dataclass(frozen=True)
class RoundsPolicy:
    """A fixed count of passes (``evsmap speed --runs N --warmup N``): ``warmup`` untimed
    passes, then rounds of ``runs`` timed ones until one has ``IQR / median <=
    stable_rel_iqr``, at most ``max_rounds``; the record keeps that round, else the steadiest
    one and says it never was stable. One round (the default) is ``runs`` passes and no more.
    The sweeps and the runner's cells time under a :class:`TimingPolicy` instead: until the
    median is precise enough."""

    runs: int = 20
    warmup: int = 3
    max_rounds: int = 1
    stable_rel_iqr: float | None = None

    def __post_init__(self) -> None:
        if self.runs < 1 or self.warmup < 0 or self.max_rounds < 1:
            raise ValueError(f"need runs >= 1, warmup >= 0 and max_rounds >= 1 (got "
                             f"runs={self.runs}, warmup={self.warmup}, "
                             f"max_rounds={self.max_rounds})")


SpeedPolicy = TimingPolicy | RoundsPolicy
"""When a speed measurement stops: until precise (:class:`TimingPolicy`) or after a fixed count
of passes (:class:`RoundsPolicy`)."""


QUICK_POLICY = TimingPolicy(target_rel_ci=0.05, min_runs=3, budget_s=3.0, max_runs=30,
                            warmup=1, warmup_s=0.0)
"""``--quick``'s rule: a smoke test, not a figure to quote."""


@dataclass(frozen=True)
class TimedPasses:
    """What :func:`time_until_precise` measured.

    Attributes:
        times_s: every timed pass, in order, seconds.
        warmup_runs: untimed passes before them.
        stopped: why timing stopped (:data:`STOP_REASONS`).
        ci_s: the median's confidence interval (low, high), seconds.
        rel_ci: its half-width (the larger side) over the median: the precision reached.
        timed_s: seconds spent on the timed passes.
        policy: the rule followed (:meth:`TimingPolicy.as_dict`).
    """

    times_s: list[float]
    warmup_runs: int
    stopped: str
    ci_s: tuple[float, float]
    rel_ci: float
    timed_s: float
    policy: dict[str, Any] = field(default_factory=dict)


def median_ci(times: Any, *, confidence: float = 0.95, resamples: int = 2000,
              seed: int = 0) -> tuple[float, float, float]:
    """``(median, low, high)``: the sample median and its percentile-bootstrap
    ``confidence`` interval (``resamples`` resamples with a generator seeded with ``seed``)."""
    x = np.asarray(times, dtype=np.float64)
    if x.size == 0:
        raise ValueError("no times")
    median = float(np.median(x))
    if x.size == 1:
        return median, median, median
    rng = np.random.default_rng(seed)
    medians = np.median(x[rng.integers(0, x.size, size=(resamples, x.size))], axis=1)
    tail = (1.0 - confidence) / 2.0 * 100.0
    low, high = np.percentile(medians, [tail, 100.0 - tail])
    return median, float(low), float(high)


def relative_half_width(median: float, low: float, high: float) -> float:
    """The larger side of an interval around ``median``, as a share of it."""
    return max(median - low, high - median) / median if median > 0 else float("inf")


def time_until_precise(call: Callable[..., object], policy: TimingPolicy, *,
                       clock: Callable[[], float] = time.perf_counter,
                       setup: Callable[[int], Any] | None = None,
                       pass_timer: Callable[[Callable[[], object]], float] | None = None
                       ) -> TimedPasses:
    """Warm up, then time ``call()`` pass by pass under ``policy`` (module docstring).

    With ``setup``, pass ``i`` times ``call(setup(i))`` and ``setup(i)`` is not timed (e.g.
    reading frame ``i`` of a sequence before a network segments it); warm-up passes use
    ``setup(0)``. With ``pass_timer`` (:class:`evsmap.devices.PassTimer`: CUDA events on a
    GPU) a pass's time is what it returns; ``clock`` still keeps the budget."""
    start = clock()
    warm = 0
    first = setup(0) if setup is not None else None
    while warm < policy.max_warmup and (warm < policy.warmup or
                                        clock() - start < policy.warmup_s):
        call() if setup is None else call(first)
        warm += 1
    times: list[float] = []
    began = clock()
    checked_at = 0
    stopped = ""
    while not stopped:
        arg = setup(len(times)) if setup is not None else None
        t0 = clock()
        if pass_timer is None:
            call() if setup is None else call(arg)
            t1 = clock()
            times.append(t1 - t0)
        else:
            times.append(pass_timer(call if setup is None else functools.partial(call, arg)))
            t1 = clock()
        n = len(times)
        if n < policy.min_runs:
            continue
        if n >= policy.max_runs:
            stopped = "max_runs"
        elif t1 - began >= policy.budget_s:
            stopped = "budget"
        elif _check_due(n, checked_at, times[-1]):
            checked_at = n
            if relative_half_width(*median_ci(times, confidence=policy.confidence,
                                              resamples=policy.resamples)) \
                    <= policy.target_rel_ci:
                stopped = "precision"
    median, low, high = median_ci(times, confidence=policy.confidence,
                                  resamples=policy.resamples)
    return TimedPasses(times_s=times, warmup_runs=warm, stopped=stopped, ci_s=(low, high),
                       rel_ci=relative_half_width(median, low, high),
                       timed_s=clock() - began, policy=policy.as_dict())


def _check_due(n: int, last: int, pass_s: float) -> bool:
    """Whether to compute the interval again: after every pass of a slow network, every tenth
    of the passes so far for a fast one (the bootstrap costs a few milliseconds)."""
    return pass_s >= 0.05 or n - last >= max(1, n // 10)


def sum_precision(parts: list[tuple[float, float]]) -> float:
    """The precision (relative half-width) of a sum of medians, from each part's ``(median,
    relative half-width)``: the parts' half-widths added (a conservative bound)."""
    total = sum(m for m, _ in parts)
    return sum(m * r for m, r in parts) / total if total > 0 else float("inf")
