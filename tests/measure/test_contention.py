"""The calibration that tells a contended timing from a clean one."""

from __future__ import annotations

import pytest

from evsmap.measure import contention


def _clock(durations):
    """A perf_counter whose successive (start, end) pairs are ``durations`` seconds apart."""
    stamps, t = [], 0.0
    for d in durations:
        stamps += [t, t + d]
        t += d + 1.0
    it = iter(stamps)
    return lambda: next(it)


@pytest.mark.parametrize(("durations", "expected_ms"), [
    ([2e-3] * 5 + [1e-3] * 10, 1.0),  # a blip under the first burst only: not contention
    ([2e-3] * 15, 2.0),  # every burst slow: a job shares the cores
    ([1e-3, 9e-3, 1e-3, 9e-3, 9e-3] * 3, 9.0),  # gaps of full speed do not hide it
])
def test_calibration_is_the_best_burst_median(monkeypatch, durations, expected_ms):
    monkeypatch.setattr(contention.time, "perf_counter", _clock(durations))
    monkeypatch.setattr(contention.time, "sleep", lambda s: None)
    got = contention.calibration_gmacs(size=100, repeats=5, bursts=3, warmup=0)
    assert got == pytest.approx(100.0 ** 3 / (expected_ms * 1e-3) / 1e9)


def test_contention_flags_a_slow_probe_against_the_best():
    def probe(g):
        return contention.Probe(load1=0.1, load5=0.1, cores=2, calibration_gmacs=g)

    log = contention.CalibrationLog()
    calm = contention.contention(probe(100.0), probe(95.0), log)
    assert not calm["contended"] and calm["slowdown"] == pytest.approx(100 / 95)
    busy = contention.contention(probe(50.0), probe(98.0), log)
    assert busy["contended"] and busy["slowdown"] == pytest.approx(2.0)


def test_calibrated_ratio_cancels_the_machine_drift_between_two_timings():
    from evsmap.measure.speed import calibrated_ratio

    # the same two networks, the machine 25 % slower while the second was timed
    assert calibrated_ratio(20.0, 100.0, 2.0 * 0.75, 75.0) == pytest.approx(10.0)
    assert calibrated_ratio(20.0, None, 2.0, 75.0) == pytest.approx(10.0)  # plain without


def test_other_processes_share_of_the_cores_flags_a_cell_the_matmul_misses():
    # 2 cores, 10 s: the machine was busy 15 CPU-s, of which 5 were ours -> others used half
    before, after = (100.0, 1000.0, 50.0), (110.0, 1015.0, 55.0)
    assert contention.other_share(before, after, 2) == pytest.approx(0.5)
    assert contention.other_share(before, None, 2) is None
    # a window of a few clock ticks says nothing: one tick of another process in 2 ms
    assert contention.other_share((100.0, 1000.0, 50.0), (100.002, 1000.01, 50.0), 2) is None

    def probe(g, cpu):
        return contention.Probe(load1=1.0, load5=1.0, cores=2, calibration_gmacs=g, cpu=cpu)

    machine = contention.contention(probe(100.0, before), probe(99.0, after))
    assert machine["slowdown"] < 1.4 and machine["other_share"] == pytest.approx(0.5)
    assert machine["contended"] and machine["severity"] == pytest.approx(0.5 / 0.15)
    assert "other processes used 50 % of the cores" in contention.describe(machine)
    calm = contention.contention(probe(100.0, before), probe(99.0, (110.0, 1005.2, 55.0)))
    assert not calm["contended"] and calm["other_share"] == pytest.approx(0.01)


def test_cpu_clock_reads_this_machine():
    clock = contention.cpu_clock()
    if clock is None:
        pytest.skip("no /proc/stat here")
    wall, busy, own = clock
    assert busy > 0 and own > 0 and wall > 0
