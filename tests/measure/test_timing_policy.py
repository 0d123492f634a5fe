"""The timing rule of the speed cells: warm-up, a floor of passes, then stop on precision,
budget or the most passes; the interval and why it stopped are kept."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import torch

from evsmap.measure.timing_policy import (
    TimingPolicy,
    median_ci,
    relative_half_width,
    time_until_precise,
)


class FakeClock:
    """A clock that each call of the timed function moves by the next duration."""

    def __init__(self, durations):
        self.now = 0.0
        self.durations = iter(durations)
        self.calls = 0

    def __call__(self) -> float:
        return self.now

    def work(self) -> None:
        self.calls += 1
        self.now += next(self.durations)


def _run(durations, policy):
    clock = FakeClock(durations)
    return time_until_precise(clock.work, policy, clock=clock), clock


def test_steady_passes_stop_on_precision_at_the_floor():
    result, clock = _run(itertools.repeat(0.1), TimingPolicy(warmup=2, warmup_s=0.0))
    assert result.stopped == "precision"
    assert result.warmup_runs == 2 and len(result.times_s) == 3  # the floor
    assert result.rel_ci == pytest.approx(0.0, abs=1e-9)
    assert result.ci_s == (pytest.approx(0.1), pytest.approx(0.1))
    assert clock.calls == 5


def test_noisy_slow_passes_stop_on_the_budget_with_the_precision_reached():
    rng = np.random.default_rng(1)
    durations = (2.0 * (1 + 0.3 * rng.standard_normal()) for _ in itertools.count())
    result, _ = _run(durations, TimingPolicy(budget_s=10.0, warmup=1, warmup_s=0.0))
    assert result.stopped == "budget"
    assert len(result.times_s) == 5  # 10 s of 2 s passes
    assert result.rel_ci > 0.03
    median = float(np.median(result.times_s))
    assert result.ci_s[0] <= median <= result.ci_s[1]


def test_max_runs_caps_a_measurement_that_never_settles():
    durations = itertools.cycle([0.001, 0.003])
    result, _ = _run(durations, TimingPolicy(max_runs=40, target_rel_ci=0.001, warmup=0,
                                             warmup_s=0.0, budget_s=100.0))
    assert result.stopped == "max_runs" and len(result.times_s) == 40


def test_warm_up_lasts_its_passes_and_its_seconds():
    result, _ = _run(itertools.repeat(0.25), TimingPolicy(warmup=1, warmup_s=1.0))
    assert result.warmup_runs == 4  # 1 s of 0.25 s passes
    result, _ = _run(itertools.repeat(3.0), TimingPolicy(warmup=2, warmup_s=1.0))
    assert result.warmup_runs == 2


def test_median_ci_is_seeded_and_brackets_the_median():
    times = np.random.default_rng(0).lognormal(0.0, 0.2, 50)
    first, second = median_ci(times), median_ci(times)
    assert first == second
    median, low, high = first
    assert low < median < high
    assert relative_half_width(median, low, high) == pytest.approx(
        max(median - low, high - median) / median)
    assert median_ci([3.0]) == (3.0, 3.0, 3.0)


@pytest.mark.parametrize("bad", [{"target_rel_ci": 0.0}, {"min_runs": 1}, {"budget_s": 0},
                                 {"max_runs": 2}, {"warmup": -1}, {"confidence": 1.0}])
def test_bad_policies_are_refused(bad):
    with pytest.raises(ValueError):
        TimingPolicy(**bad)


def test_measure_speed_keeps_the_interval_and_why_it_stopped(monkeypatch):
    import evsmap.measure.speed as speed

    monkeypatch.setattr(speed, "time_until_precise", lambda call, policy, **_: _run(
        itertools.repeat(0.004), policy)[0])
    rec = speed.measure_speed(torch.nn.Conv2d(1, 1, 1), torch.zeros(1, 1, 4, 4), macs=1,
                              policy=TimingPolicy(), roofline=10.0)
    assert rec.stopped == "precision" and rec.rel_ci == 0.0 and rec.runs == 3
    assert rec.ci_ms == [pytest.approx(4.0), pytest.approx(4.0)]
    assert rec.roofline_gmacs == 10.0 and rec.policy["target_rel_ci"] == 0.03
