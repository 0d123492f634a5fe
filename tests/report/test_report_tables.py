import dataclasses
import math
import re

import pandas as pd
import pytest
from conftest import extra, make_records, spec_key

from evsmap.report.tables import (
    FRAME_COLUMNS,
    extra_frame,
    format_number,
    format_ratio,
    table_frame,
    table_markdown,
)
from evsmap.runner.records import CellRecord
from evsmap.tables import expand_all, load_tables


@pytest.fixture(scope="module")
def tables():
    return load_tables()


@pytest.fixture(scope="module")
def records():
    return {r.key: r for r in make_records()}


@pytest.fixture(scope="module")
def specs():
    return expand_all(available=["dataset:tum"])


def with_paper_only(table, *row_ids):
    """``table`` with ``row_ids`` marked not implemented: no row of the paper's tables is paper
    only any more (every compared network is a plug-in), so the rendering of one is tested on a
    copy."""
    rows = tuple(dataclasses.replace(r, implemented=False) if r.id in row_ids else r
                 for r in table.rows)
    return dataclasses.replace(table, rows=rows)


def line(frame, row, column):
    sel = frame[(frame["row"] == row) & (frame["column"] == column)]
    assert len(sel) == 1
    return sel.iloc[0]


def md_cell(md, label, header):
    """The text of the markdown table cell of row ``label`` under ``header``."""
    lines = [x for x in md.splitlines() if x.startswith("| ")]
    headers = [h.strip() for h in lines[0].strip("|").split(" | ")]
    for x in lines[1:]:
        cells = [c.strip() for c in re.split(r"(?<!\\)\|", x.strip())[1:-1]]
        if cells[0].split(" [")[0].removesuffix(" (paper only)") == label:
            return cells[headers.index(header)]
    raise AssertionError(f"row {label!r} not in the markdown")


def footnote(md, ref):
    n = ref.strip("[]")
    for x in md.splitlines():
        if x.startswith(f"{n}. "):
            return x[len(n) + 2:]
    raise AssertionError(f"footnote {ref} missing")


def test_format_number():
    assert format_number(4.278, 1) == "4.28"  # at least three significant digits
    assert format_number(4.28, 2) == "4.28"
    assert format_number(0.0123, 1) == "0.0123"
    assert format_number(5.0, 0) == "5.00"
    assert format_number(123.4, 0) == "123"
    assert format_number(1234.5, 1) == "1234.5"
    assert format_number(7.5, None) == "7.50"
    assert format_ratio(0.951) == "0.95x" and format_ratio(0.0123) == "0.012x"


def test_frame_has_every_row_and_measured_column(tables, records, specs):
    for table in tables.values():
        frame = table_frame(table, records, specs)
        assert tuple(frame.columns) == FRAME_COLUMNS
        cols = [c.id for c in table.columns if c.kind != "flag"]
        assert len(frame) == len(table.rows) * len(cols)
        assert list(dict.fromkeys(frame["row"])) == [r.id for r in table.rows]
        assert set(frame["column"]) == set(cols)
        assert set(frame["status"]) <= {"ok", "n/a", "error", "not run", "no value",
                                        "paper only"}


def test_multi_column_record_values_and_ratio(tables, records, specs):
    frame = table_frame(tables["table1"], records, specs)
    params = line(frame, "feagnet-v2", "params")
    assert params["status"] == "ok"
    assert params["measured"] == pytest.approx(4.28) and params["paper"] == pytest.approx(4.5)
    assert params["ratio"] == pytest.approx(4.28 / 4.5)
    assert params["note"] == "fvcore FLOPs at 640x480"
    flops = line(frame, "feagnet-v2", "flops")  # the same record fills both columns
    assert flops["measured"] == pytest.approx(7.5) and flops["ratio"] == pytest.approx(7.5 / 7.8)
    fps = line(frame, "feagnet-v2", "fps")
    assert fps["measured"] == pytest.approx(20.07) and fps["paper"] == pytest.approx(37.7)
    t4 = table_frame(tables["table4"], records, specs)
    size = line(t4, "orgbmap", "size_seq1")
    assert size["measured"] == pytest.approx(1.234) and size["unit"] == "MB"
    assert size["ratio"] == pytest.approx(1.234 / 3.54)
    assert "tum" in size["note"]  # the sequence it was measured on


def test_na_error_missing_and_paper_only(tables, records, specs):
    frame = table_frame(with_paper_only(tables["table1"], "3dgnn-r101"), records, specs)
    na = line(frame, "feagnet-v2", "miou_nyuv2")
    assert na["status"] == "n/a" and math.isnan(na["measured"]) and math.isnan(na["ratio"])
    assert na["note"] == ("n/a - needs the nyuv2 dataset, needs trained weights "
                          "(feagnet-v2@nyuv2)")
    assert na["paper"] == pytest.approx(47.6)
    err = line(frame, "feagnet-v1", "fps")
    assert err["status"] == "error" and err["note"] == "error: RuntimeError: boom"
    assert math.isnan(err["measured"])
    missing = line(frame, "esanet-r34", "params")
    assert missing["status"] == "not run" and missing["note"] == "not run"
    only = frame[frame["row"] == "3dgnn-r101"]
    assert set(only["status"]) == {"paper only"} and only["measured"].isna().all()
    assert math.isnan(line(frame, "3dgnn-r101", "flops")["paper"])  # blank in the paper
    t3 = table_frame(tables["table3"], records, specs)
    novalue = line(t3, "basel", "flops")
    assert novalue["status"] == "no value" and math.isnan(novalue["measured"])


def test_record_under_an_unknown_key_still_fills_its_cell(tables):
    rec = CellRecord(key="table1/feagnet-v2/complexity/other-options", table="table1",
                     row="feagnet-v2", label="FEAGNet-V2", kind="complexity",
                     metrics=["params"], status="ok", values={"params": 4.0e6})
    frame = table_frame(tables["table1"], {rec.key: rec})
    assert line(frame, "feagnet-v2", "params")["measured"] == pytest.approx(4.0)


def test_markdown_cells(tables, records, specs):
    md = table_markdown(with_paper_only(tables["table1"], "3dgnn-r101", "rdfnet-r101",
                                        "pgdenet-r34"), records, specs)
    assert md.startswith("# Table I - FEAGNet compared to SOTA networks on NYUv2 and SUN RGBD")
    assert tables["table1"].note.split(";")[0] in md
    # measured / paper (ratio), measured with the paper's decimals (>= 2 significant digits)
    assert md_cell(md, "FEAGNet-V2", "Params (M)").startswith("4.28 / 4.5 (0.95x)")
    # no measured ÷ paper for a speed: it would divide this CPU by the paper's GPU
    assert md_cell(md, "FEAGNet-V2", "FPS").startswith("20.1 / 37.7 [")
    # n/a: the reason as a footnote, never a number on the measured side
    na = md_cell(md, "FEAGNet-V2", "MIoU NYUv2 (%)")
    assert re.fullmatch(r"n/a / 47\.6 \[\d+\]", na), na
    assert footnote(md, na.split()[-1]) == ("n/a - needs the nyuv2 dataset, needs trained "
                                            "weights (feagnet-v2@nyuv2)")
    jetson = md_cell(md, "FEAGNet-V2*", "FPS")
    assert jetson.startswith("n/a / 52.5 [")
    assert footnote(md, jetson.split()[-1]) == "n/a - needs jetson-tensorrt hardware"
    err = md_cell(md, "FEAGNet-V1", "FPS")
    assert err.startswith("error / 39.2 [")
    assert footnote(md, err.split()[-1]) == "error: RuntimeError: boom"
    assert md_cell(md, "ESANet-R34Δ (2021)", "Params (M)") == "not run / 46.9"
    # paper-only rows, blank paper cells, marks and bold as printed
    assert md_cell(md, "3DGNN-R101 (2017)", "MIoU NYUv2 (%)") == "- / 43.1"
    assert md_cell(md, "3DGNN-R101 (2017)", "FLOPs (G)") == "- / -"
    assert md_cell(md, "RDFNet-R101 (2017)", "FPS") == "- / 7.9†"
    assert md_cell(md, "PGDENet-R34 (2023)", "MIoU NYUv2 (%)") == "- / **53.7**"
    assert md_cell(md, "FEAGNet-V2*", "Params (M)") == "not run / **4.5**"
    # identical notes share one footnote
    assert md.count("fvcore FLOPs at 640x480") == 1


def test_every_row_and_column_in_markdown(tables, records, specs):
    for table in tables.values():
        md = table_markdown(table, records, specs)
        header = next(x for x in md.splitlines() if x.startswith("| System"))
        for col in table.columns:
            assert col.header.replace("|", "\\|") in header, (table.id, col.id)
        body = [x for x in md.splitlines() if x.startswith("| ")][1:]
        assert len(body) == len(table.rows)
        for system, text in zip(table.rows, body, strict=True):
            assert text.startswith(f"| {system.label}"), (table.id, system.id)


def test_table3_flags_as_printed(tables, records, specs):
    md = table_markdown(tables["table3"], records, specs)
    assert md_cell(md, "Basel. + CFIM", "CFIM") == "√"
    assert md_cell(md, "Basel. + CFIM", "DAPPF") == ""
    assert md_cell(md, "Basel. + CFIM + DAPPF + WA&HA + ML",
                   "Params (M)") == "4.45 / 4.45 (1.00x)"
    frame = table_frame(tables["table3"], records, specs)
    assert "cfim" not in set(frame["column"])


def test_table4_extras_section(tables, records, specs):
    extras = [r for r in records.values() if r.key.startswith("extra/")]
    md = table_markdown(tables["table4"], records, specs, extras=extras)
    # every rate in the fixture comes from the synthetic room, and the header says so
    assert md_cell(md, "MVSMMap", "Runtime (Hz), measured on synthetic").startswith(
        "3.21 / 14.4 [")
    section = md.split("## Measured beyond the paper", 1)[1]
    assert "### Sequence `synthetic`, voxel size 0.05 m" in section
    assert "### Sequence `tum`, voxel size 0.05 m" in section
    # columns: rates, published and full size, memory (OctoMap's formula, then measured: evsmap
    # arrays, peak RSS added by mapping), nodes, leaves, pruned, then the 3D scores (accuracy
    # of the labelled voxels and with no class counted wrong, mIoU)
    assert ("| MVSMMap [1] | 12.5 | 3.21 | 2.50 | - | 8.10 | - | 34.2 | - | - | - | 95.1 | 80.2 "
            "| 87.5 | - | 61.3 |" in section)
    assert ("| OctoMap (C++) | 45.0 | 45.0 | 1.20 | - | 3.00 | - | - | - | - | - | - | - | - "
            "| - | - |" in section)
    assert re.search(r"\| TESAMap \[\d\] \| n/a \| n/a", section)
    assert "n/a - needs trained weights (esanet@nyuv2)" in section


def test_extra_frame_base_units():
    frame = extra_frame(make_records())
    assert len(frame) == 5
    ev = frame[frame["key"] == "extra/mapping/evsmap/synthetic@0.05m"].iloc[0]
    assert ev["map_bytes"] == 2.5e6 and ev["precision"] == pytest.approx(0.951)
    assert ev["sequence"] == "synthetic" and ev["resolution"] == 0.05
    na = frame[frame["row"] == "tesamap"].iloc[0]
    assert na["status"] == "n/a" and pd.isna(na["update_hz"])


def test_spec_key_helper_matches_expand():
    assert spec_key("table1", "feagnet-v2", "complexity") == \
        "table1/feagnet-v2/complexity@640x480[params,flops]"


def test_size_claim_says_plainly_whether_it_reproduces():
    from evsmap.report.tables import size_claim_lines

    def pair(slam_bytes, slam_nodes, ev_bytes, ev_nodes):
        return [extra("tfeagmap", "TFEAGMap", "tum", "ok",
                      values={"map_bytes": slam_bytes, "nodes": slam_nodes}),
                extra("evsmap", "MVSMMap", "tum", "ok",
                      values={"map_bytes": ev_bytes, "nodes": ev_nodes})]

    text = size_claim_lines(pair(81_000, 10_000, 554_000, 23_000))[0]
    assert "0.15x" in text and "does not reproduce: EVSMap's map is the larger one" in text
    assert "Bytes a node in the file: 8.1 against 24.1" in text and "(2.30x)" in text
    assert "that reproduces" in size_claim_lines(pair(3e6, 1e5, 1e6, 4e4))[0]
    assert "smaller, by less" in size_claim_lines(pair(2e6, 1e5, 1e6, 4e4))[0]
    # one side missing or not measured: nothing to say
    assert size_claim_lines(pair(81_000, 10_000, 554_000, 23_000)[:1]) == []


def test_flagged_timings_are_marked_in_the_table(tables, specs):
    from dataclasses import replace

    records = {r.key: r for r in make_records()}
    key = next(k for k, r in records.items() if r.kind == "speed" and r.status == "ok")
    records[key] = replace(records[key], details={"timing_flag": "unstable: IQR/median 0.21 "
                                                                "after 4 rounds of 10"},
                           notes=records[key].notes + ["timing flagged - unstable"])
    table = tables[records[key].table]
    md = table_markdown(table, records, specs)
    label = next(s.label for s in table.rows if s.id == records[key].row)
    header = next(c for c in table.columns if c.id == records[key].metrics[0])
    from evsmap.report.tables import header_with_unit

    assert " ~ / " in md_cell(md, label, header_with_unit(header))
    frame = table_frame(table, records, specs)
    flagged = frame[frame["timing_flag"].notna()]
    assert len(flagged) == 1 and "unstable" in flagged.iloc[0]["timing_flag"]


def test_cosmetics_headers_ratios_counts_and_skipped_cells(tables):
    from evsmap.report.tables import extra_frame, header_with_unit

    t2 = tables["table2"]
    fps = next(c for c in t2.columns if c.id == "fps_1024")
    assert header_with_unit(fps) == "1024×512 (val) FPS"  # not "... FPS (FPS)"
    assert format_ratio(0.04) == "0.040x" and format_ratio(0.0634) == "0.063x"
    spec = next(s for s in expand_all(tables) if s.table == "table2" and s.kind == "speed"
                and "fps_2048" in s.metrics)
    frame = table_frame(t2, {}, None, {spec.key: "skipped by --quick (input above 1024x512)"})
    line = frame[(frame["column"] == "fps_2048") & (frame["row"] == spec.row)].iloc[0]
    assert line["status"] == "not run" and line["note"].startswith("skipped by --quick")
    paper = frame[(frame["row"] == "esanet-r34") & (frame["column"] == "fps_1024")].iloc[0]
    assert paper["paper_printed"] == "17.6†"  # the paper's marks survive in the CSV
    rec = CellRecord(key="extra/mapping/evsmap/synthetic@0.05m", table="extra", row="evsmap",
                     label="EVSMap", kind="mapping", metrics=[], status="ok",
                     values={"map_bytes": 1234.0, "nodes": 7.0, "update_hz": 2.5},
                     inputs={"sequence": "synthetic", "resolution": 0.05})
    csv = extra_frame([rec]).to_csv(index=False)
    assert ",1234," in csv and ",7," in csv and "1234.0" not in csv


def test_gpu_speed_rows_say_whether_their_pass_was_launch_bound(tables, specs):
    from dataclasses import replace

    from evsmap.report.tables import BOUND_HEADER

    records = {r.key: r for r in make_records()}
    key = next(k for k, r in records.items() if r.kind == "speed" and r.status == "ok")
    table = tables[records[key].table]
    label = next(s.label for s in table.rows if s.id == records[key].row)
    cpu_md = table_markdown(table, records, specs)
    assert BOUND_HEADER not in cpu_md  # a CPU run's table keeps its columns
    records[key] = replace(records[key], details={
        "device": "cuda:0", "busy": {"kernel_ms": 3.1, "busy_share": 0.23, "bound": "launch"}})
    md = table_markdown(table, records, specs)
    assert md_cell(md, label, BOUND_HEADER) == "23 % busy, launch-bound"
    rows = [x for x in md.splitlines() if x.startswith("| ") and "---" not in x][1:]
    assert sum("-bound" in x for x in rows) == 1  # the CPU-timed rows leave it empty
    frame = table_frame(table, records, specs)
    row = frame[frame["bound"].notna()]
    assert len(row) == 1 and row.iloc[0]["busy_share"] == pytest.approx(0.23)
