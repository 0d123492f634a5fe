"""``reproduce --resume --out RUN`` takes the run's own settings from its ``run.json`` when they
are not given again; a given one that would change what the run measures is refused. The cells
are faked (in-process, instant): only the settings are under test."""

from __future__ import annotations

import json

import pytest
from runner_fixtures import Inline

import evsmap.runner.matrix as matrix
from evsmap.cli.main import main
from evsmap.runner.records import CellRecord


@pytest.fixture
def counted_cells(monkeypatch):
    calls: list[str] = []

    def execute_spec(spec, ctx):
        calls.append(spec.key)
        return CellRecord(key=spec.key, table=spec.table, row=spec.row, label=spec.label,
                          kind=spec.kind, metrics=list(spec.metrics), status="ok",
                          values={m: 1.0 for m in spec.metrics})

    monkeypatch.setattr(matrix, "execute_spec", execute_spec)
    monkeypatch.setattr(matrix, "_spawn_pool", Inline)
    monkeypatch.setattr(matrix, "_fresh_executor", Inline)
    return calls


CELLS = "table1/feagnet-v1/complexity*,table1/feagnet-v2/*"


@pytest.fixture
def quick_run(tmp_path, counted_cells, capsys):
    out = tmp_path / "run"
    assert main(["reproduce", "--quick", "--tables", "I", "--cells", CELLS, "--workers", "1",
                 "--data-root", str(tmp_path), "--out", str(out)]) == 0
    capsys.readouterr()
    return out


def test_the_run_records_its_settings(quick_run, tmp_path):
    run = json.loads((quick_run / "run.json").read_text())
    settings = run["settings"]
    assert settings["quick"] is True and settings["workers"] == 1
    assert settings["cells"] == CELLS.split(",")
    assert settings["data_root"] == str(tmp_path) and settings["precision"] == "fp32"
    assert all(key.startswith(("table1/feagnet-v1/complexity", "table1/feagnet-v2/"))
               for key in run["cells"])


def test_resume_alone_continues_with_the_runs_settings(quick_run, counted_cells, capsys):
    first = json.loads((quick_run / "run.json").read_text())
    # a cell lost (as if the run had been stopped before it): only it runs again
    lost = sorted((quick_run / "records").glob("*.json"))[0]
    key = json.loads(lost.read_text())["key"]
    lost.unlink()
    counted_cells.clear()
    assert main(["reproduce", "--resume", "--out", str(quick_run)]) == 0
    assert counted_cells == [key]
    again = json.loads((quick_run / "run.json").read_text())
    assert again["settings"] == first["settings"] and again["cells"] == first["cells"]
    assert again["tables"] == first["tables"] and again["run"] == first["run"]


@pytest.mark.parametrize(("extra", "message"), [
    (["--no-quick"], "was made with --quick"),
    (["--cells", "table1/*"], "was made with --cells"),
    (["--precision", "int8"], "was made with --precision fp32"),
    (["--train"], "was made without --train"),
    (["--tables", "I,IV"], "covers tables table1"),
])
def test_resume_refuses_settings_that_change_what_is_measured(quick_run, capsys, extra,
                                                              message):
    assert main(["reproduce", "--resume", "--out", str(quick_run), *extra]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1, err


def test_resume_may_change_where_and_how_it_runs(quick_run, counted_cells, tmp_path):
    counted_cells.clear()
    assert main(["reproduce", "--resume", "--out", str(quick_run), "--workers", "2",
                 "--data-root", str(tmp_path)]) == 0
    assert counted_cells == []  # everything had finished
    settings = json.loads((quick_run / "run.json").read_text())["settings"]
    assert settings["workers"] == 2


def test_cells_that_match_nothing_are_one_line(tmp_path, counted_cells, capsys):
    assert main(["reproduce", "--quick", "--tables", "I", "--cells", "table9/*", "--out",
                 str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err
    assert "--cells table9/*: no cell of tables table1 matches" in err
    assert not (tmp_path / "run").exists()


def test_a_full_disk_mid_run_keeps_the_records_and_resume_finishes(tmp_path, counted_cells,
                                                                   capsys, monkeypatch):
    import errno

    from tests.test_disk_full import fail_writes

    out = tmp_path / "run"
    # run.json and two records go through; the disk is full at the third record
    seen = fail_writes(monkeypatch, out, errno.ENOSPC, skip=3)
    code = main(["reproduce", "--quick", "--tables", "I", "--cells", CELLS, "--workers", "1",
                 "--data-root", str(tmp_path), "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2 and seen["failed"] == 1
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "No space left on device" in lines[0], err
    assert str(out / "records") in lines[0]
    kept = sorted((out / "records").iterdir())
    assert len(kept) == 2 and all(p.suffix == ".json" for p in kept)  # no temporary left
    for p in kept:
        CellRecord.from_dict(json.loads(p.read_text()))  # whole

    monkeypatch.undo()  # space again
    monkeypatch.setattr(matrix, "execute_spec", counted_cells_execute(counted_cells))
    monkeypatch.setattr(matrix, "_spawn_pool", Inline)
    monkeypatch.setattr(matrix, "_fresh_executor", Inline)
    assert main(["reproduce", "--resume", "--out", str(out)]) == 0
    run = json.loads((out / "run.json").read_text())
    assert len(list((out / "records").glob("*.json"))) == len(run["cells"])


def counted_cells_execute(calls):
    def execute_spec(spec, ctx):
        calls.append(spec.key)
        return CellRecord(key=spec.key, table=spec.table, row=spec.row, label=spec.label,
                          kind=spec.kind, metrics=list(spec.metrics), status="ok",
                          values={m: 1.0 for m in spec.metrics})

    return execute_spec
