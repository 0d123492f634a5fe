"""`evsmap compare`: shared cells side by side with precisions, ratios with their own precision,
exact cells equal or not, the machines at the top, cells apart, the paper as a column, the plot,
and one-line refusals."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from benchmarks import ship_run
from evsmap.cli.main import main
from evsmap.report.compare import (
    PAPER,
    Cell,
    Value,
    compare_runs,
    compare_values,
    ratio_precision,
)
from evsmap.report.compare_text import compare_frame, compare_json, compare_markdown

ROOT = Path(__file__).resolve().parents[2]
SHIPPED = ship_run.shipped(ROOT / "results")
FULL = next(f for f in SHIPPED if f.name.endswith("_full"))
QUICK = next(f for f in SHIPPED if f.name.endswith("_quick"))
FPS = Cell("table1", "x", "fps", "X", "FPS", "FPS", timed=True)
PARAMS = Cell("table1", "x", "params", "X", "Params (M)", "M", timed=False)


def test_a_timed_ratio_carries_both_relative_half_widths():
    a, b = Value(10.0, rel=0.02), Value(12.0, rel=0.03)
    assert ratio_precision(a, b) == pytest.approx(0.05)
    r = compare_values(FPS, a, b, paper=False)
    assert r.ratio == pytest.approx(1.2) and r.rel == pytest.approx(0.05)
    assert r.verdict == "differs"  # 1.2 lies 20 % off, outside +-5 %
    r = compare_values(FPS, a, Value(10.4, rel=0.03), paper=False)
    assert r.verdict == "within precision"
    assert compare_values(FPS, Value(10.0), b, paper=False).verdict == "no precision"


def test_exact_cells_are_equal_or_differ_and_the_paper_by_its_printed_digits():
    assert compare_values(PARAMS, Value(4.28), Value(4.28), paper=False).verdict == "equal"
    assert compare_values(PARAMS, Value(4.28), Value(4.2801), paper=False).verdict == "differ"
    printed = Value(4.5, rel=0.05 / 4.5, decimals=1)
    assert compare_values(PARAMS, printed, Value(4.46), paper=True).verdict == "equal"
    assert compare_values(PARAMS, printed, Value(4.28), paper=True).verdict == "differ"


def test_the_full_and_the_quick_run_share_cells_with_ratios_and_precisions():
    comparison = compare_runs([FULL, QUICK])
    assert len(comparison.shared) > 20 and comparison.apart  # the quick run skips cells
    cid = "table1/feagnet-v1/fps"
    a, b = (c.values[cid] for c in comparison.columns)
    (ratio,) = comparison.ratios[cid]
    assert ratio.ratio == pytest.approx(b.value / a.value)
    assert ratio.rel == pytest.approx(a.rel + b.rel)
    (params,) = comparison.ratios["table1/feagnet-v1/params"]
    assert params.verdict == "equal" and params.rel is None  # the same network's count
    md = compare_markdown(comparison)
    assert md.count("AMD EPYC, avx512-vnni, 2 cores") >= 1
    commits = [json.loads((f / "run.json").read_text())["environment"]["git_commit"][:12]
               for f in (FULL, QUICK)]
    assert all(c in md for c in commits)
    assert "## Measured in only some of the runs" in md
    frame = compare_frame(comparison)
    assert set(frame["run"]) == {FULL.name, QUICK.name}
    assert not frame[frame["shared"]]["value"].isna().any()


def _other_machine(tmp_path: Path, factor: float) -> Path:
    """The quick run as if measured on another machine kind, every speed ``factor`` times."""
    run = tmp_path / "other"
    run.mkdir()
    data = json.loads((QUICK / "run.json").read_text())
    data["environment"] |= {"cpu": "Other CPU 9000", "instruction_set": "avx2", "cpus": 8,
                            "git_commit": "0123456789abcdef"}
    (run / "run.json").write_text(json.dumps(data))
    (run / "records").mkdir()
    for path in (QUICK / "records").glob("*.json"):
        rec = json.loads(path.read_text())
        if rec["kind"] == "speed" and rec["status"] == "ok":
            rec["values"] = {k: v * factor for k, v in rec["values"].items()}
        (run / "records" / path.name).write_text(json.dumps(rec))
    return run


def test_two_machine_kinds_compare_through_the_command(tmp_path, capsys):
    other = _other_machine(tmp_path, 2.0)
    out = tmp_path / "cmp"
    assert main(["compare", str(QUICK), str(other), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "Other CPU 9000, avx2, 8 cores" in text and "AMD EPYC, avx512-vnni, 2 cores" in text
    assert "2.00x" in text and "differs" in text
    data = json.loads((out / "compare.json").read_text())
    kinds = [c["kind"] for c in data["columns"]]
    assert all(kinds) and kinds[0] != kinds[1]
    fps = next(c for c in data["shared"] if c["cell"] == "table1/feagnet-v1/fps")
    assert fps["ratios"][other.name]["ratio"] == pytest.approx(2.0)
    assert {p.name for p in out.iterdir()} == {"compare.md", "compare.csv", "compare.json",
                                              "compare.tex", "speed.png"}
    assert (out / "speed.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_the_paper_is_a_column_like_a_run():
    comparison = compare_runs([QUICK], paper=True)
    assert [c.name for c in comparison.columns] == [QUICK.name, PAPER]
    (params,) = comparison.ratios["table1/feagnet-v1/params"]
    assert params.verdict == "differ"  # 4.28 M measured, 4.5 printed
    data = compare_json(compare_runs([PAPER, QUICK]))
    assert data["columns"][0]["name"] == PAPER and data["ratio_of"] == f"each run / {PAPER}"


@pytest.mark.parametrize("argv, named", [
    (["compare", "{quick}"], "{quick}"),
    (["compare", "{missing}", "{quick}"], "{missing}"),
    (["compare", "{tmp}", "{quick}"], "{tmp}"),
    (["compare", "{quick}", "{quick}"], "{quick}"),
])
def test_bad_input_is_one_line_naming_the_path(argv, named, tmp_path, capsys):
    paths = {"quick": str(QUICK), "missing": str(tmp_path / "nope"), "tmp": str(tmp_path)}
    assert main([a.format(**paths) for a in argv]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and named.format(**paths) in err


def test_the_speed_plot_is_drawn(tmp_path):
    from evsmap.report.compare_plot import speed_plot, speed_points

    other = _other_machine(tmp_path, 0.5)
    comparison = compare_runs([QUICK, other])
    points = speed_points(comparison, 1)
    assert points and all(p["y"] == pytest.approx(0.5 * p["x"]) for p in points)
    assert speed_plot(comparison, tmp_path / "speed.png")
    shutil.rmtree(other)
