"""The estimate is the run's, not only its cells': a timed cell costs its whole wait (the
fresh process's start-up included), and the time outside the cells comes from this machine's
last run, else the reference's scaled."""

from __future__ import annotations

import json

import pytest

from evsmap.runner.estimate import OUTSIDE_KEY, Estimator, cell_duration
from evsmap.runner.records import CellRecord


def _reference(tmp_path, monkeypatch, **extra):
    reference = tmp_path / "reference.json"
    reference.write_text(json.dumps({"machine": {"calibration_gmacs": 100.0},
                                     "run": {"quick": False}, "cells": {"a": 10.0, "b": 20.0},
                                     **extra}))
    monkeypatch.setattr("evsmap.runner.estimate.REFERENCE_FILES",
                        {False: reference, True: reference})


def test_the_reference_time_outside_cells_is_scaled_and_shared_out(tmp_path, monkeypatch):
    _reference(tmp_path, monkeypatch, outside={"seconds": 120.0, "cells": 2})
    est = Estimator.load(threads=2, calibration_gmacs=50.0, cache_root=tmp_path)
    assert est.outside == (240.0, 2)  # a machine half as fast
    items = [("a", "speed"), ("b", "speed")]
    assert est.run_s(items) == pytest.approx(60.0 + 240.0)
    assert est.run_s(items[:1]) == pytest.approx(20.0 + 120.0)  # half the cells, half of it
    assert est.remaining_s([]) == 0.0


def test_this_machines_last_run_is_learnt_and_preferred(tmp_path, monkeypatch):
    _reference(tmp_path, monkeypatch, outside={"seconds": 120.0, "cells": 2})
    est = Estimator.load(threads=2, calibration_gmacs=100.0, cache_root=tmp_path)
    est.learn_outside(30.0, 2)
    again = Estimator.load(threads=2, calibration_gmacs=100.0, cache_root=tmp_path)
    assert again.outside == (30.0, 2) and OUTSIDE_KEY not in again.history
    assert again.run_s([("a", "speed"), ("b", "speed")]) == pytest.approx(30.0 + 30.0)


def test_a_reference_without_it_adds_nothing(tmp_path, monkeypatch):
    _reference(tmp_path, monkeypatch)
    est = Estimator.load(threads=2, calibration_gmacs=100.0, cache_root=tmp_path)
    assert est.outside is None and est.run_s([("a", "speed")]) == 10.0


def test_a_timed_cell_costs_its_whole_wait():
    rec = CellRecord(key="k", table="t", row="r", label="R", kind="speed", metrics=[],
                     status="ok", seconds=8.0)
    assert cell_duration(rec) == 8.0  # untimed, or a record before the accounting
    rec.around = {"wall_s": 14.5, "start_s": 5.0, "cell_s": 8.0}
    assert cell_duration(rec) == 14.5
