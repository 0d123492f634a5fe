"""The gate's comparator: slowed, grown, changed and missing measurements fail, naming the
workload; noise within the thresholds passes; clearly better ones hint at --update."""

from __future__ import annotations

import pytest

from evsmap.gate.compare import Thresholds, compare, entry_of, summary, table

MiB = 2**20


def record(name="net/x/torch", time_ratio=10.0, peak=200 * MiB, **counts):
    return {"name": name, "time_ratio": time_ratio, "peak_rss_bytes": peak,
            "workload_ms": 120.0, "calibration_ms": 12.0, "pairs": 9,
            "counts": counts or {"params": 1000, "output_sha256": "ab12"}}


def baseline_of(*records):
    return {r["name"]: entry_of(r) for r in records}


def verdicts(rows, workload, measure):
    return [r.verdict for r in rows if r.workload == workload and r.measure == measure]


def test_the_same_measurements_pass_and_the_entry_keeps_counts_flat():
    rec = record()
    entry = entry_of(rec)
    assert entry["params"] == 1000 and entry["output_sha256"] == "ab12"
    assert entry["context"]["workload_ms"] == 120.0
    rows = compare(baseline_of(rec), {rec["name"]: rec})
    assert {r.verdict for r in rows} == {"ok"}
    passed, text = summary(rows)
    assert passed and "gate passed: 1 workloads" in text and "--update" not in text


@pytest.mark.parametrize("factor, verdict", [(1.10, "ok"), (1.149, "ok"), (1.16, "FAIL"),
                                             (1.5, "FAIL"), (0.90, "ok"), (0.8, "better")])
def test_time_ratio_fails_above_15_percent(factor, verdict):
    base = record()
    now = record(time_ratio=10.0 * factor)
    rows = compare(baseline_of(base), {base["name"]: now})
    assert verdicts(rows, base["name"], "time_ratio") == [verdict]
    assert summary(rows)[0] == (verdict != "FAIL")


def test_a_uniformly_slower_project_fails_every_workload_and_names_them():
    base = [record(f"net/n{i}/torch") for i in range(3)] + [record("read/tum", 30.0)]
    now = {r["name"]: {**r, "time_ratio": r["time_ratio"] * 1.5} for r in base}
    rows = compare(baseline_of(*base), now)
    passed, text = summary(rows)
    assert not passed
    assert "4 of 4 workloads" in text
    for r in base:
        assert r["name"] in text
    assert "+50.0%" in table(rows)


@pytest.mark.parametrize("grown, verdict", [(1.09, "ok"), (1.12, "FAIL"), (0.85, "better")])
def test_peak_memory_fails_above_10_percent(grown, verdict):
    base = record(peak=300 * MiB)
    rows = compare(baseline_of(base), {base["name"]: record(peak=int(300 * MiB * grown))})
    assert verdicts(rows, base["name"], "peak_rss_bytes") == [verdict]


def test_small_peaks_need_more_than_the_slack_to_fail():
    base = record(peak=8 * MiB)
    # +25 % but only 2 MiB: allocator and page granularity, not a regression
    rows = compare(baseline_of(base), {base["name"]: record(peak=10 * MiB)})
    assert verdicts(rows, base["name"], "peak_rss_bytes") == ["ok"]
    rows = compare(baseline_of(base), {base["name"]: record(peak=11 * MiB)})
    assert verdicts(rows, base["name"], "peak_rss_bytes") == ["FAIL"]
    # a zero slack holds even small workloads to 10 %
    rows = compare(baseline_of(base), {base["name"]: record(peak=10 * MiB)},
                   Thresholds(memory_slack_bytes=0))
    assert verdicts(rows, base["name"], "peak_rss_bytes") == ["FAIL"]


def test_an_exact_count_that_changes_fails_even_when_time_and_memory_hold():
    base = record(params=1000, output_sha256="ab12")
    rows = compare(baseline_of(base),
                   {base["name"]: record(params=1001, output_sha256="ab12")})
    bad = [r for r in rows if r.failed]
    assert [(r.measure, r.baseline, r.now) for r in bad] == [("params", 1000, 1001)]
    assert "an exact count changed" in table(rows)
    rows = compare(baseline_of(base), {base["name"]: record(params=1000)})
    assert [r.measure for r in rows if r.failed] == ["output_sha256"]


def test_a_baselined_workload_that_did_not_run_fails_with_its_reason():
    a, b = record("read/tum"), record("read/rosbag")
    rows = compare(baseline_of(a, b), {
        "read/tum": {"name": "read/tum", "error": "DataFormatError: rgb.txt: bad line 3"},
    })
    assert verdicts(rows, "read/tum", "-") == ["FAIL"]
    assert verdicts(rows, "read/rosbag", "-") == ["FAIL"]
    md = table(rows)
    assert "rgb.txt: bad line 3" in md and "not measured" in md


def test_a_new_workload_passes_with_the_update_hint_and_unbaselined_skips_do_not_fail():
    a = record("net/a/torch")
    rows = compare(baseline_of(a), {"net/a/torch": a, "net/mine/torch": record("net/mine/torch"),
                                    "read/rosbag": {"name": "read/rosbag",
                                                    "skipped": "needs the sample"}})
    passed, text = summary(rows)
    assert passed
    assert verdicts(rows, "net/mine/torch", "-") == ["new"]
    assert verdicts(rows, "read/rosbag", "-") == ["skipped"]
    assert "evsmap gate --update" in text and "net/mine/torch" in text


def test_the_table_prints_ratios_mebibytes_and_signed_changes():
    base = record(peak=100 * MiB)
    rows = compare(baseline_of(base), {base["name"]: record(time_ratio=12.0, peak=100 * MiB)})
    md = table(rows)
    assert md.splitlines()[0] == "| workload | measure | baseline | now | change | verdict |"
    assert "| net/x/torch | time_ratio | 10 | 12 | +20.0% | FAIL: more than 15% above" in md
    assert "| net/x/torch | peak_rss_bytes | 100.0 MiB | 100.0 MiB | +0.0% | ok |" in md


def test_on_another_machine_kind_only_structural_counts_are_held():
    base = record(params=1000, nodes=500, output_sha256="ab12")
    now = record(time_ratio=20.0, peak=400 * MiB, params=1000, nodes=507,
                 output_sha256="ff00")
    rows = compare(baseline_of(base), {base["name"]: now}, same_machine=False)
    assert not any(r.failed for r in rows)
    assert {r.measure for r in rows if r.verdict == "not compared"} == {
        "time_ratio", "peak_rss_bytes", "nodes", "output_sha256"}
    passed, text = summary(rows)
    assert passed and "WARNING: this machine is of another kind" in text
    # a parameter count does not depend on the CPU: still held
    rows = compare(baseline_of(base), {base["name"]: record(params=999, nodes=500,
                                                             output_sha256="ab12")},
                   same_machine=False)
    assert [r.measure for r in rows if r.failed] == ["params"]


def test_a_time_ratio_taken_against_another_calibration_is_not_judged_as_equal():
    base = {"w": {"time_ratio": 10.0, "peak_rss_bytes": 100 * 2**20,
                  "context": {"calibration": "compute"}}}
    now = {"w": {"time_ratio": 10.0, "peak_rss_bytes": 100 * 2**20, "calibration": "memory",
                 "counts": {}}}
    rows = {r.measure: r for r in compare(base, now)}
    assert rows["time_ratio"].verdict == "FAIL" and "calibration" in rows["time_ratio"].why
    assert rows["peak_rss_bytes"].verdict == "ok"
