"""index.md's "Timing precision": the rule, the distribution of the speed cells' precision,
the cells that stopped on their budget, exports and peak memory."""

from __future__ import annotations

from evsmap.measure.timing_policy import TimingPolicy
from evsmap.report.precision import precision_markdown, speed_precision
from evsmap.runner.records import CellRecord


def _speed(row, rel, stopped, export_s=None, peak=0):
    return CellRecord(key=f"table1/{row}/speed@640x480[fps]", table="table1", row=row,
                      label=row.upper(), kind="speed", metrics=["fps"], status="ok",
                      values={"fps": 10.0}, seconds=12.0, cell_peak_rss_bytes=peak,
                      details={"rel_ci": rel, "stopped": stopped, "runs": 5,
                               "export": {"export_s": export_s, "size_free": True}})


def test_the_section_states_rule_distribution_budget_cells_and_peaks():
    records = [_speed("a", 0.01, "precision", 2.0, 2**30), _speed("b", 0.02, "precision"),
               _speed("c", 0.08, "budget", 9.0, 3 * 2**30)]
    text = "\n".join(precision_markdown(records, TimingPolicy().as_dict()))
    assert "## Timing precision" in text and "within +-3%" in text
    assert "median +-2.0 %" in text and "worst +-8.0 %" in text
    assert "2 reached the target, 1 stopped on its budget" in text
    assert "Stopped on their budget, with the precision reached: C 640x480 +-8.0 %" in text
    assert "2 made in this run (11 s)" in text
    assert "Peak memory of a cell: 3.00 GiB (C" in text


def test_no_speed_cell_no_section_and_old_records_read():
    assert precision_markdown([], None) == []
    old = CellRecord(key="table1/x/speed@640x480[fps]", table="table1", row="x", label="X",
                     kind="speed", metrics=["fps"], status="ok", values={"fps": 1.0},
                     details={"rel_iqr": 0.05, "rounds": 2})
    assert speed_precision([old])[0]["rel_ci"] is None
    assert "## Timing precision" in "\n".join(precision_markdown([old], None))
