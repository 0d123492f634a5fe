import json

import numpy as np
import pandas as pd
import pytest
from conftest import make_records, make_run

from evsmap.cli.main import main
from evsmap.errors import DataFormatError
from evsmap.report import build_report
from evsmap.report.plots import split_map_name, top_down
from evsmap.runner.records import RecordStore
from evsmap.tables import load_tables

PNG = b"\x89PNG\r\n\x1a\n"


def test_writes_every_file(built_run):
    root, written = built_run
    names = [p.name for p in written]
    for tid in ("table1", "table2", "table3", "table4"):
        assert f"{tid}.md" in names and f"{tid}.csv" in names
    assert {"extra.csv", "networks.png", "mapping.png", "qualitative.png"} <= set(names)
    assert names[-1] == "index.md"
    assert all(p.parent == root and p.is_file() for p in written)
    for name in ("networks.png", "mapping.png", "qualitative.png"):
        assert (root / name).read_bytes()[:8] == PNG


def test_csv_values(built_run):
    root, _ = built_run
    frame = pd.read_csv(root / "table1.csv")
    sel = frame[(frame["row"] == "feagnet-v2") & (frame["column"] == "params")].iloc[0]
    assert sel["measured"] == pytest.approx(4.28) and sel["paper"] == pytest.approx(4.5)
    assert sel["ratio"] == pytest.approx(4.28 / 4.5) and sel["status"] == "ok"
    na = frame[(frame["row"] == "feagnet-v2") & (frame["column"] == "miou_nyuv2")].iloc[0]
    assert pd.isna(na["measured"]) and na["note"].startswith("n/a - needs the nyuv2 dataset")
    tables = load_tables()
    for tid, table in tables.items():
        f = pd.read_csv(root / f"{tid}.csv")
        assert len(f) == len(table.rows) * sum(c.kind != "flag" for c in table.columns)
    extra = pd.read_csv(root / "extra.csv")
    assert len(extra) == 5 and set(extra["sequence"]) == {"synthetic", "tum"}


def test_table4_markdown_has_extras(built_run):
    root, _ = built_run
    md = (root / "table4.md").read_text()
    assert md.startswith("# Table IV - ")
    assert "## Measured beyond the paper" in md and "OctoMap (C++)" in md


def test_index(built_run):
    root, _ = built_run
    index = (root / "index.md").read_text()
    assert "run 20250101-120000" in index and "Test CPU @ 3 GHz" in index
    assert "| instruction set | avx2 |" in index and "| vector flags | sse4_2, avx, avx2, fma |" \
        in index
    assert "| octomap-python | not installed |" in index
    assert "`dataset:tum`" in index and "/data" in index
    # ok / n/a / error / not run / no value / paper only for Table I: every row is implemented
    # (the comparison networks), so the cells the fixture has no record of are "not run"
    assert "| Table I: FEAGNet compared to SOTA networks on NYUv2 and SUN RGBD | 5 | 2 | 1 | " \
           "62 | 0 | 0 |" in index
    for link in ("table1.md", "table4.csv", "extra.csv", "networks.png", "mapping.png",
                 "qualitative.png"):
        assert f"]({link})" in index
    assert "evsmap datasets prepare" in index and "--weights-dir" in index
    assert "<segmenter>@<dataset>.pt" in index and "Jetson" in index


def test_plots_skipped_without_data(tmp_path):
    root = make_run(tmp_path / "run", records=[], artifacts=False)
    (root / "networks.png").write_bytes(b"stale")
    written = build_report(root)
    names = {p.name for p in written}
    assert not names & {"networks.png", "mapping.png", "qualitative.png", "extra.csv"}
    assert not (root / "networks.png").exists()  # a stale figure is removed
    index = (root / "index.md").read_text()
    assert "networks.png: skipped" in index and "qualitative.png: skipped" in index
    assert "| 0 | 0 | 0 | 70 | 0 | 0 |" in index  # Table I: nothing run, no row paper only


def test_missing_and_corrupt_inputs(tmp_path):
    with pytest.raises(DataFormatError, match="no such run folder"):
        build_report(tmp_path / "nope")
    (tmp_path / "empty").mkdir()
    with pytest.raises(DataFormatError, match="run.json"):
        build_report(tmp_path / "empty")
    root = make_run(tmp_path / "bad", records=make_records()[:2], artifacts=False)
    (root / "run.json").write_text("{not json")
    with pytest.raises(DataFormatError, match="run.json"):
        build_report(root)
    root = make_run(tmp_path / "badrec", records=make_records()[:2], artifacts=False)
    bad = RecordStore(root).path(make_records()[0].key)
    data = json.loads(bad.read_text())
    data["values"]["params"] = "many"
    bad.write_text(json.dumps(data))
    with pytest.raises(DataFormatError, match=bad.name):
        build_report(root)
    bad.write_text(json.dumps({"key": "x"}))
    with pytest.raises(DataFormatError, match=bad.name):
        build_report(root)


def test_cli_report(built_run, capsys):
    root, _ = built_run
    code = main(["report", str(root)])
    out, err = capsys.readouterr()
    assert code == 0 and err == ""
    printed = out.splitlines()
    assert str(root / "table1.md") in printed and printed[-1] == str(root / "index.md")


def test_cli_report_errors(tmp_path, capsys):
    code = main(["report", str(tmp_path / "missing")])
    _, err = capsys.readouterr()
    assert code == 2 and err.count("\n") == 1 and "no such run folder" in err
    root = make_run(tmp_path / "run", records=make_records()[:1], artifacts=False)
    (root / "records" / "broken.json").write_text("[1, 2")
    code = main(["report", str(root)])
    _, err = capsys.readouterr()
    assert code == 2 and err.count("\n") == 1 and "broken.json" in err


def test_top_down_keeps_the_highest_voxel():
    centres = np.array([[0.01, 0.01, 0.0], [0.02, 0.02, 1.0], [0.5, 0.5, 0.3]])
    top = top_down(centres, 0.05)
    assert sorted(top.tolist()) == [1, 2] and top.tolist() == [2, 1]  # sorted by height
    assert top_down(np.zeros((0, 3)), 0.05).size == 0


def test_split_map_name(tmp_path):
    assert split_map_name(tmp_path / "map-octomap-cpp-synthetic.npz") == ("octomap-cpp",
                                                                          "synthetic")
    assert split_map_name(tmp_path / "map-evsmap-tum.npz") == ("evsmap", "tum")
    assert split_map_name(tmp_path / "map-other-seq.npz") == ("other", "seq")


def test_proxy_maps_stay_out_of_the_mapping_plot():
    from evsmap.report.plots import mapping_entries
    from evsmap.runner.records import CellRecord

    base = CellRecord(key="extra/mapping/evsmap/synthetic@0.05m", table="extra", row="evsmap",
                      label="EVSMap", kind="mapping", metrics=[], status="ok",
                      inputs={"sequence": "synthetic", "resolution": 0.05},
                      values={"update_hz": 20.0})
    proxy = CellRecord.from_dict({**base.as_dict(),
                                  "key": "extra/proxy-mapping/evsmap/synthrooms-room20",
                                  "label": "EVSMap + proxy feagnet-v1",
                                  "inputs": {"sequence": "synthrooms-room20",
                                             "resolution": 0.05},
                                  "values": {"update_hz": 58.0}})
    entries = mapping_entries([base, proxy])
    assert [(e["sequence"], e["update_hz"]) for e in entries] == [("synthetic", 20.0)]
