"""A first run in a cache pays for exports, counts and compiles that later runs find cached: the
history keeps its durations apart, so the next run is not estimated at a cold run's cost."""

from __future__ import annotations

import json

import pytest

from evsmap.runner.estimate import FIRST_KEY, OUTSIDE_KEY, Estimator, machine_id


def _reference(tmp_path, monkeypatch, *, warm=True):
    reference = tmp_path / "reference.json"
    data = {"machine": {"calibration_gmacs": 100.0}, "run": {"quick": False},
            "outside": {"seconds": 100.0, "cells": 2}, "cells": {"a": 40.0, "b": 20.0}}
    if warm:
        data["warm"] = {"outside": {"seconds": 20.0, "cells": 2}, "cells": {"a": 10.0, "b": 20.0}}
    reference.write_text(json.dumps(data))
    monkeypatch.setattr("evsmap.runner.estimate.REFERENCE_FILES",
                        {False: reference, True: reference})


def _load(tmp_path, gmacs=100.0):
    return Estimator.load(threads=2, calibration_gmacs=gmacs, cache_root=tmp_path)


def test_a_new_cache_is_estimated_as_the_references_first_run(tmp_path, monkeypatch):
    _reference(tmp_path, monkeypatch)
    est = _load(tmp_path, gmacs=50.0)  # half as fast
    assert est.first
    assert est.seconds("a", "speed") == (80.0, "reference")
    assert est.run_s([("a", "speed"), ("b", "speed")]) == pytest.approx(120.0 + 200.0)


def test_a_first_runs_durations_are_kept_apart_and_scaled_to_a_later_run(tmp_path, monkeypatch):
    _reference(tmp_path, monkeypatch)
    first = _load(tmp_path)
    first.learn("a", "speed", 60.0)  # this machine: 1.5x the reference's first run
    first.learn_outside(50.0, 2)
    stored = json.loads((tmp_path / "durations.json").read_text())[machine_id(2)]
    assert set(stored) == {FIRST_KEY} and stored[FIRST_KEY]["a"] == 60.0
    assert stored[FIRST_KEY][OUTSIDE_KEY] == {"seconds": 50.0, "cells": 2}

    later = _load(tmp_path)
    assert not later.first and later.history == {}
    # the cell's own first run, times the reference's later-over-first ratio (10/40)
    assert later.seconds("a", "speed") == (15.0, "history (first run, scaled)")
    # a cell this machine never ran: the reference's later run
    assert later.seconds("b", "speed") == (20.0, "reference")
    assert later.outside == (pytest.approx(10.0), 2)  # 50 x 20/100


def test_a_later_runs_durations_are_preferred_and_kept_flat(tmp_path, monkeypatch):
    _reference(tmp_path, monkeypatch)
    _load(tmp_path).learn("a", "speed", 60.0)
    later = _load(tmp_path)
    later.learn("a", "speed", 12.0)
    later.learn_outside(8.0, 2)
    third = _load(tmp_path)
    assert third.seconds("a", "speed") == (12.0, "history")
    assert third.outside == (8.0, 2)
    stored = json.loads((tmp_path / "durations.json").read_text())[machine_id(2)]
    assert stored["a"] == 12.0 and stored[FIRST_KEY]["a"] == 60.0  # the first run's kept


def test_without_a_warm_reference_a_first_runs_figure_is_used_as_is(tmp_path, monkeypatch):
    _reference(tmp_path, monkeypatch, warm=False)
    _load(tmp_path).learn("a", "speed", 60.0)
    assert _load(tmp_path).seconds("a", "speed") == (60.0, "history (first run, scaled)")


def test_a_history_written_before_the_split_reads_as_later_runs(tmp_path, monkeypatch):
    _reference(tmp_path, monkeypatch)
    (tmp_path / "durations.json").write_text(json.dumps({machine_id(2): {"a": 33.0}}))
    est = _load(tmp_path)
    assert not est.first and est.seconds("a", "speed") == (33.0, "history")
