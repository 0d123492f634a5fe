"""The claims' cells run before the compared networks; --budget leaves out what does not fit;
the time estimate learns from the finished cells."""

from __future__ import annotations

import json

import pytest

from evsmap.runner import matrix
from evsmap.runner.context import RunContext
from evsmap.runner.estimate import Budget, Estimator, format_duration
from evsmap.runner.records import CellRecord
from evsmap.tables.claims import claims_first
from tests.runner.runner_fixtures import Inline


@pytest.fixture
def full_ctx(tmp_path):
    empty = tmp_path / "data"
    empty.mkdir()
    return RunContext.create(tmp_path / "run", data_root=empty)


@pytest.fixture
def calls(monkeypatch):
    seen: list[str] = []

    def execute_spec(spec, ctx):
        seen.append(spec.key)
        return CellRecord(key=spec.key, table=spec.table, row=spec.row, label=spec.label,
                          kind=spec.kind, metrics=list(spec.metrics), status="ok",
                          values={m: 1.0 for m in spec.metrics}, seconds=2.0)

    monkeypatch.setattr(matrix, "execute_spec", execute_spec)
    return seen


def _run(ctx, plan, **kw):
    return matrix.run_matrix(ctx, plan, pool=lambda n: Inline(), fresh=Inline, **kw)


def test_the_claims_cells_run_before_the_compared_networks(full_ctx, calls):
    plan = matrix.plan(full_ctx, ["table1", "table2", "table3"])
    _run(full_ctx, plan)
    table = {s.key: s for s in plan.specs}
    order = [claims_first(table[k].table, table[k].row) for k in calls]
    assert 0 in order and 1 in order
    assert order == sorted(order)  # every claims cell (0) before any compared network's (1)
    first = {table[k].row for k in calls if claims_first(table[k].table, table[k].row) == 0}
    assert {"feagnet-v2", "esanet-r34", "basel"} <= first
    assert "rdfnet-r101" not in first


def test_quick_leaves_the_compared_networks_out(tmp_path):
    ctx = RunContext.create(tmp_path / "run", quick=True)
    plan = matrix.plan(ctx, ["table1"])
    rows = {s.row for s in plan.specs if not s.needs}
    assert "feagnet-v2" in rows and "esanet-r34" in rows and "rdfnet-r101" not in rows
    why = dict(plan.skipped)
    assert why["table1/rdfnet-r101/speed@640x480[fps]"].startswith(
        "skipped by --quick (a compared network")


def test_budget_records_what_does_not_fit_as_not_measured(full_ctx, calls):
    plan = matrix.plan(full_ctx, ["table1"])
    estimator = Estimator()  # defaults: 10 s a complexity cell, 30 s a speed cell
    records = {r.key: r for r in _run(full_ctx, plan, budget=Budget(0.25),
                                      estimator=estimator)}
    # 15 s of budget: one complexity cell's 10 s fits at a time, no speed cell's 30 s
    speed = records["table1/feagnet-v2/speed@640x480[fps]"]
    assert speed.status == "na" and speed.needs == ["time"]
    assert speed.reason.startswith("n/a - left out by --budget 0.25 (estimated 30 s")
    assert not any(k.endswith("speed@640x480[fps]") for k in calls)
    assert any("complexity" in k for k in calls)


def test_estimates_come_from_history_then_reference_then_defaults(tmp_path, monkeypatch):
    reference = tmp_path / "reference.json"
    reference.write_text(json.dumps({"machine": {"calibration_gmacs": 100.0},
                                     "cells": {"a": 10.0, "b": 4.0}}))
    monkeypatch.setattr("evsmap.runner.estimate.REFERENCE_FILES",
                        {False: reference, True: reference})
    est = Estimator.load(threads=2, calibration_gmacs=50.0, cache_root=tmp_path)
    assert est.seconds("a", "speed") == (20.0, "reference")  # a machine half as fast
    assert est.seconds("z", "mapping") == (60.0, "default")
    est.learn("a", "speed", 30.0)  # estimated 20 s, took 30 s
    assert est.seconds("a", "speed") == (30.0, "history (first run)")
    # 30 s taken for 20 estimated, each from a prior of 60 s of "as estimated"
    assert est.correction() == pytest.approx(90 / 80)
    assert est.remaining_s([("b", "speed")]) == pytest.approx(8.0 * 90 / 80)
    est.learn("c", "mapping", 600.0)  # a long cell at 10x its default of 60 s moves it a lot
    assert est.correction() == pytest.approx(min(3.0, 690 / 140))
    again = Estimator.load(threads=2, calibration_gmacs=50.0, cache_root=tmp_path)
    # kept in durations.json (no later run on the reference machine to scale it by)
    assert again.seconds("a", "speed") == (30.0, "history (first run, scaled)")
    assert Estimator.load(threads=4, calibration_gmacs=50.0,
                          cache_root=tmp_path).seconds("a", "speed")[1] == "reference"


def test_the_correction_is_bounded_and_durations_read_well():
    est = Estimator()
    est.learn("x", "speed", 3000.0)  # 100x the default estimate
    assert est.correction() == 3.0
    assert [format_duration(s) for s in (45, 600, 3900)] == ["45 s", "10 min", "1 h 05 min"]


def test_budget_refuses_once_the_time_is_spent():
    assert Budget(1.0).refuses(30.0) is None
    assert "left out by --budget 1" in Budget(1.0).refuses(120.0)


def test_quick_runs_keep_their_own_history_and_skip_the_full_reference(tmp_path, monkeypatch):
    reference = tmp_path / "reference.json"
    reference.write_text(json.dumps({"machine": {"calibration_gmacs": 100.0},
                                     "run": {"quick": False}, "cells": {"a": 10.0}}))
    monkeypatch.setattr("evsmap.runner.estimate.REFERENCE_FILES",
                        {False: reference, True: reference})
    quick = Estimator.load(threads=2, calibration_gmacs=100.0, cache_root=tmp_path, quick=True)
    assert quick.seconds("a", "speed") == (30.0, "default")
    quick.learn("a", "speed", 2.0)
    full = Estimator.load(threads=2, calibration_gmacs=100.0, cache_root=tmp_path)
    assert full.seconds("a", "speed") == (10.0, "reference")  # the quick 2 s stays apart


@pytest.mark.parametrize("value", ["x", 1.5, True])
def test_a_record_whose_peak_is_not_an_integer_is_one_clear_error(value):
    from evsmap.errors import DataFormatError

    data = {"key": "a", "table": "table1", "row": "r", "label": "R", "kind": "speed",
            "metrics": [], "status": "ok", "cell_peak_rss_bytes": value}
    with pytest.raises(DataFormatError, match="'cell_peak_rss_bytes' must be an integer"):
        CellRecord.from_json(data, source="f.json")


def test_a_mapping_run_without_its_dataset_is_not_pending(full_ctx):
    """ScanNet's detail runs are n/a without the dataset: they cost no time and so are not
    in the estimate (they had cost a default 60 s each: 3 min on a 2.8 min --quick run)."""
    from evsmap.runner.reproduce import pending_cells

    the_plan = matrix.plan(full_ctx, ["table4"])
    sequences = {r.sequence for r in the_plan.runs}
    assert "scannet" in sequences and "synthetic" in sequences
    pending = {key for key, kind in pending_cells(full_ctx, the_plan, resume=False)
               if kind == "mapping"}
    assert pending and not any("scannet" in key for key in pending)
    assert any(key.endswith("synthetic@0.02m") for key in pending)
