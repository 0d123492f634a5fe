"""Every second of a run in a named phase (evsmap.runner.accounting): the run's phases add up
to its wall time, the time around each timed cell is split into its parts, and the report's
"Where the time went" section says both."""

from __future__ import annotations

import pytest
from runner_fixtures import Inline

import evsmap.runner.matrix as matrix
from evsmap.report.accounting import accounting_markdown, around_totals
from evsmap.runner.accounting import AROUND, PHASES, RunClock, process_age_s, settle_around
from evsmap.runner.context import RunContext
from evsmap.runner.records import CellRecord


def test_spans_from_the_worker_and_driver_stamps():
    around = {"entered": 102.0, "began": 103.5, "left": 110.0}
    spans = settle_around(around, 6.0, submitted=100.0, received=111.0)
    assert spans == {"wall_s": 11.0, "cell_s": 6.0, "retry_s": 0.0, "start_s": 2.0,
                     "setup_s": 1.5, "finish_s": 0.5, "return_s": 1.0}
    assert sum(spans[k] for k in AROUND) == pytest.approx(spans["wall_s"])
    # a second try: the first one and its pause are the retry
    again = settle_around(around, 6.0, submitted=100.0, received=111.0, first_submitted=60.0)
    assert again["retry_s"] == 40.0 and again["wall_s"] == 51.0
    # an executor without the worker's stamps: the wait and the cell only
    assert set(settle_around({}, 6.0, 100.0, 111.0)) == {"wall_s", "cell_s", "retry_s"}


def test_run_clock_adds_phases_and_refuses_unknown_ones(monkeypatch):
    import evsmap.runner.accounting as accounting

    now = iter([1000.0, 1000.0, 1004.0, 1010.0])
    monkeypatch.setattr(accounting, "stamp", lambda: next(now))
    clock = RunClock()  # begun at 1000
    clock.add("start-up", 2.0)
    with clock.phase("plan"):  # 1000 -> 1004
        pass
    data = clock.as_dict()  # at 1010: 10 s of run + 2 s of start-up
    assert data["wall_s"] == 12.0 and data["phases"] == {"start-up": 2.0, "plan": 4.0}
    assert data["unaccounted_s"] == 6.0
    with pytest.raises(ValueError, match="unknown run phase"):
        clock.add("lunch", 1.0)
    assert process_age_s() is None or process_age_s() > 0


def test_a_run_matrix_accounts_for_its_phases_and_its_timed_cells(tmp_path, monkeypatch):
    empty = tmp_path / "data"
    empty.mkdir()
    ctx = RunContext.create(tmp_path / "run", data_root=empty, quick=True)

    def execute_spec(spec, ctx):
        return CellRecord(key=spec.key, table=spec.table, row=spec.row, label=spec.label,
                          kind=spec.kind, metrics=list(spec.metrics), status="ok",
                          values={m: 1.0 for m in spec.metrics}, seconds=0.0,
                          around={"began": matrix.stamp()})

    monkeypatch.setattr(matrix, "execute_spec", execute_spec)
    plan = matrix.plan(ctx, ["table1"])
    clock = RunClock()
    records = matrix.run_matrix(ctx, plan, pool=lambda n: Inline(), fresh=Inline, clock=clock)
    phases = clock.as_dict()["phases"]
    assert {"n/a cells", "untimed cells", "timed cells"} <= set(phases)
    assert list(phases) == [p for p in PHASES if p in phases]
    speed = [r for r in records if r.kind == "speed" and r.status == "ok"]
    assert speed and all(set(AROUND) <= set(r.around) for r in speed)
    assert all(r.around["wall_s"] >= r.around["cell_s"] for r in speed)
    pooled = [r for r in records if r.kind == "complexity" and r.status == "ok"]
    assert pooled and all(r.around["pooled"] == 1.0 for r in pooled)  # a share of the pool's
    copies = [r for r in pooled if any("same configuration as" in n for n in r.notes)]
    assert copies and all(r.around["wall_s"] == 0.0 for r in copies)  # measured once
    assert "timed cells" in around_totals(records) and all(
        "pooled" not in r.around for r in records if r.kind == "speed" and r.status == "ok")
    # stored with the record and read back
    from evsmap.runner.records import RecordStore

    assert RecordStore(ctx.out).get(speed[0].key).around == speed[0].around


def test_the_report_section_adds_up_and_names_the_parts():
    accounting = {"wall_s": 600.0, "phases": {"start-up": 6.0, "plan": 3.0,
                                              "timed cells": 500.0, "mapping runs": 80.0},
                  "unaccounted_s": 11.0}
    rec = CellRecord(key="k", table="table1", row="r", label="R", kind="speed", metrics=["fps"],
                     status="ok", around={"wall_s": 500.0, "start_s": 40.0, "setup_s": 5.0,
                                          "cell_s": 440.0, "finish_s": 5.0, "return_s": 10.0,
                                          "retry_s": 0.0})
    md = "\n".join(accounting_markdown(accounting, [rec]))
    assert "**10.0 min**" in md
    assert "| timed cells | 8.33 | 83.3 % |" in md and "| in no phase | 0.18 | 1.8 % |" in md
    assert "process spawn and imports 0.67 min" in md and "none of these" not in md
    assert around_totals([rec])["timed cells"]["start_s"] == 40.0
    assert accounting_markdown(None, [rec]) == []  # a run made before the accounting


def test_the_start_estimate_is_kept_beside_the_wall_time_and_reported():
    clock = RunClock()
    assert "estimate_s" not in clock.as_dict()
    clock.estimate_s = 1380.04
    assert clock.as_dict()["estimate_s"] == 1380.0
    accounting = {"wall_s": 1200.0, "phases": {"timed cells": 1200.0}, "unaccounted_s": 0.0,
                  "estimate_s": 1380.0}
    md = "\n".join(accounting_markdown(accounting, []))
    assert "Its start line estimated **23.0 min** (+15 % of the wall time)." in md
