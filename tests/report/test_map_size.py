"""Which Map Size: the four readings against the paper's Seq.1 ratios, the size verdicts, and
the growth plot."""

from __future__ import annotations

import pytest

from evsmap.report.map_size import (
    PAIRS,
    consistency_markdown,
    paper_ratios,
    reading_errors,
    verdict_rows,
)
from evsmap.report.plots import growth_plot
from evsmap.runner.records import CellRecord

NODES = {"orgbmap": 1000, "tesamap": 1500, "tfeagmap": 1500, "mesamap": 1600, "evsmap": 1400}


def _run(row: str, seq: str = "tum", voxel: float = 0.02, **override) -> CellRecord:
    n = NODES[row]
    message_node = 36 if row in ("mesamap", "evsmap") else 8  # SSMI's message: semantics
    values = {"map_bytes": 100 + 8 * n, "map_bytes_message": 100 + message_node * n,
              "map_bytes_colour": 100 + 8 * n,
              "octomap_memory_bytes": 48 * n if row != "orgbmap" else 16 * n, "nodes": n}
    values.update(override)
    growth = [{"frames": f, "nodes": n * f // 4, "leaves": n * f // 5,
               "published_bytes": values["map_bytes"] * f // 4,
               "message_bytes": values["map_bytes_message"] * f // 4,
               "colour_bytes": values["map_bytes_colour"] * f // 4,
               "memory_bytes": values["octomap_memory_bytes"] * f // 4} for f in (1, 2, 3, 4)]
    return CellRecord(key=f"extra/mapping/{row}/{seq}@{voxel:g}m", table="extra", row=row,
                      label=row.upper(), kind="mapping", metrics=[], status="ok",
                      values=values, inputs={"sequence": seq, "resolution": voxel},
                      details={"growth": growth})


def test_paper_ratios_come_from_the_printed_table():
    paper = paper_ratios()
    assert paper["TESAMap / ORGBMap"] == pytest.approx(5.43 / 3.54)
    assert paper["MESAMap / TESAMap"] == pytest.approx(5.89 / 5.43)
    assert paper["EVSMap / TFEAGMap"] == pytest.approx(5.30 / 5.71)


def test_each_reading_is_scored_against_the_paper():
    runs = {r: _run(r) for r in NODES}
    errors = reading_errors(runs, paper_ratios())
    ratios, error = errors["colour-only file"]
    assert ratios["TESAMap / ORGBMap"] == pytest.approx((100 + 8 * 1500) / (100 + 8 * 1000))
    assert error is not None and error >= 0
    # a missing row leaves its ratios out and the reading unscored
    partial = reading_errors({k: v for k, v in runs.items() if k != "orgbmap"}, paper_ratios())
    assert partial["C++ memory (model)"][0]["TESAMap / ORGBMap"] is None
    assert partial["C++ memory (model)"][1] is None


def test_the_table_marks_the_closest_reading_and_names_table4s():
    records = [_run(r) for r in NODES] + [_run(r, voxel=0.05) for r in NODES]
    lines = consistency_markdown(records, "C++ memory (model)")
    text = "\n".join(lines)
    assert "Which \"Map Size\"" in text and "uses the C++ memory (model)" in text
    assert text.count("| tum | 2 cm |") == 4 and text.count("| tum | 5 cm |") == 4
    assert sum(1 for line in lines if "**" in line and "| tum |" in line) == 2  # one a block
    assert all(name in text for name in PAIRS)
    assert consistency_markdown([_run("evsmap")], "x") == []  # nothing to compare


def test_verdicts_under_every_reading():
    rows = verdict_rows([_run(r) for r in NODES])
    assert len(rows) == 2 * 4  # two pairs, four readings
    message = next(r for r in rows if r.startswith("| EVSMap") and "message" in r)
    assert "does not hold" in message  # 36 B against 8 B a node
    saved = next(r for r in rows if r.startswith("| EVSMap") and "saved" in r)
    assert "| holds |" in saved  # SSMI saves 8 B a node too
    memory = next(r for r in rows if r.startswith("| EVSMap") and "memory" in r)
    assert "| holds |" in memory  # fewer nodes, the same node size


def test_growth_plot_draws_every_sequence(tmp_path):
    records = [_run(r) for r in NODES] + [_run(r, seq="synthetic-long") for r in NODES]
    assert growth_plot(records, tmp_path / "g.png")
    assert (tmp_path / "g.png").stat().st_size > 10_000
    assert not growth_plot([], tmp_path / "none.png")
