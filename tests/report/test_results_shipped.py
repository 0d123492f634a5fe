"""The runs shipped under results/: data only, named by machine and commit, and every one rebuilt
by `evsmap report` with today's code; benchmarks/ship_run.py ships a run and lists it."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from conftest import make_run

from benchmarks import ship_run
from evsmap.report.build import build_report
from evsmap.report.run_data import load_run
from evsmap.runner.record_keys import OLD_KEYS

ROOT = Path(__file__).resolve().parents[2]
SHIPPED = ship_run.shipped(ROOT / "results")


def _copy(folder: Path, dst: Path) -> Path:
    dst.mkdir(parents=True)
    shutil.copy2(folder / "run.json", dst / "run.json")
    shutil.copytree(folder / "records", dst / "records")
    return dst


def test_a_full_and_a_quick_run_are_shipped():
    quick = [json.loads((f / "run.json").read_text()).get("quick") for f in SHIPPED]
    assert True in quick and False in quick


@pytest.mark.parametrize("folder", SHIPPED, ids=lambda p: p.name)
def test_a_shipped_run_is_data_named_by_its_machine_and_commit(folder):
    assert sorted(p.name for p in folder.iterdir()
                  if not ship_run.RESULTS_IGNORED.match(p.name)) == ["records", "run.json"]
    assert folder.name == ship_run.folder_name(load_run(folder))


@pytest.mark.parametrize("folder", SHIPPED, ids=lambda p: p.name)
def test_report_rebuilds_every_shipped_run(folder, tmp_path):
    run = _copy(folder, tmp_path / folder.name)
    written = {p.name for p in build_report(run, study=None)}
    loaded = load_run(run)
    assert {f"{tid}.md" for tid in loaded.table_ids} <= written
    assert "index.md" in written
    measured = sum(int((loaded.frames[t]["status"] == "ok").sum()) for t in loaded.table_ids)
    assert measured >= 20  # the tables are filled from the records, not left "not run"
    assert "## What reproduces here" in (run / "index.md").read_text()


def test_a_shipped_record_with_the_old_keys_reads_as_today(tmp_path):
    full = next(f for f in SHIPPED if f.name.endswith("_full"))
    run = _copy(full, tmp_path / "old")
    path = next(p for p in sorted((run / "records").glob("extra_mapping_*.json"))
                if "update_hz" in json.loads(p.read_text())["values"])
    today = load_run(run).by_key[json.loads(path.read_text())["key"]].values
    data = json.loads(path.read_text())
    new_to_old = {"update_hz": "hz_median", "segment_update_hz": "end_to_end_hz",
                  "wall_hz": "hz_end_to_end"}
    assert all(OLD_KEYS[old] == new for new, old in new_to_old.items())
    for section in ("values", "details"):
        data[section] = {new_to_old.get(k, k): v for k, v in data[section].items()}
    assert "hz_median" in data["values"] and "update_hz" not in data["values"]
    assert "end_to_end_hz" in data["values"]
    path.write_text(json.dumps(data))
    assert load_run(run).by_key[data["key"]].values == today


def _results(tmp_path: Path) -> Path:
    results = tmp_path / "results"
    results.mkdir()
    text = (ROOT / "results" / "README.md").read_text()
    start, end = text.index(ship_run.LISTING_START), text.index(ship_run.LISTING_END)
    (results / "README.md").write_text(text[:start] + ship_run.LISTING_START + "\n"
                                       + ship_run.LISTING_END + text[end + len(
                                           ship_run.LISTING_END):])
    return results


def test_ship_run_copies_the_data_and_lists_it(tmp_path):
    run = make_run(tmp_path / "run")
    results = _results(tmp_path)
    assert ship_run.main([str(run), "--results", str(results)]) == 0
    (folder,) = ship_run.shipped(results)
    assert folder.name.startswith("test-cpu-3-ghz_avx2_2c_")
    assert folder.name.endswith("_abc1234_quick")
    assert sorted(p.name for p in folder.iterdir()) == ["records", "run.json"]
    assert len(list((folder / "records").glob("*.json"))) == len(
        list((run / "records").glob("*.json")))
    assert f"[`{folder.name}`]({folder.name})" in (results / "README.md").read_text()


def test_ship_run_refuses_a_second_copy_and_an_unfinished_run(tmp_path, capsys):
    run = make_run(tmp_path / "run")
    results = _results(tmp_path)
    assert ship_run.main([str(run), "--results", str(results)]) == 0
    capsys.readouterr()
    assert ship_run.main([str(run), "--results", str(results)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "already shipped" in err and "--overwrite" in err
    data = json.loads((run / "run.json").read_text())
    del data["finished"]
    (run / "run.json").write_text(json.dumps(data))
    assert ship_run.main([str(run), "--results", str(results), "--overwrite"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and str(run) in err and "did not finish" in err
