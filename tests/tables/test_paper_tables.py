"""paper_tables.toml: complete against the paper, validated, expanded into runnable cells."""

from __future__ import annotations

import copy
import re
import tomllib
from pathlib import Path

import pytest

from evsmap.tables import TableSchemaError, expand, expand_all, load_file, load_tables
from evsmap.tables.schema import default_path, parse_tables
from evsmap.testing import missing

PAPER = Path(__file__).resolve().parents[3] / "shared" / "paper" / "EVSMaP.md"


@pytest.fixture(scope="module")
def tables():
    return load_tables()


@pytest.fixture(scope="module")
def raw():
    with open(default_path(), "rb") as f:
        return tomllib.load(f)


def test_file_is_package_data():
    assert default_path().name == "paper_tables.toml" and default_path().is_file()
    pyproject = (Path(__file__).resolve().parents[2] / "pyproject.toml").read_text()
    assert '"tables/*.toml"' in pyproject


# ---------------------------------------------------------------------------- completeness
# Rows and columns counted in the paper (Tables I-IV).
EXPECTED = {
    "table1": ("I", 14, ["miou_nyuv2", "miou_sunrgbd", "params", "flops", "fps"]),
    "table2": ("II", 17, ["miou_1024", "fps_1024", "miou_2048", "fps_2048", "params"]),
    "table3": ("III", 6, ["basel", "cfim", "dappf", "waha", "ml", "miou", "params", "flops"]),
    "table4": ("IV", 5, ["runtime", "size_seq1", "size_seq2", "size_seq3", "size_seq4",
                         "size_seq5"]),
}


def test_every_table_row_and_column(tables):
    assert sorted(tables) == sorted(EXPECTED)
    for tid, (number, n_rows, cols) in EXPECTED.items():
        t = tables[tid]
        assert t.number == number
        assert len(t.rows) == n_rows, tid
        assert [c.id for c in t.columns] == cols, tid
        assert len(t.cells) == n_rows * len(cols)  # every cell is written, blanks as "-"


def test_row_labels_in_paper_order(tables):
    labels = {tid: [r.label for r in t.rows] for tid, t in tables.items()}
    assert labels["table1"] == [
        "3DGNN-R101", "RDFNet-R101", "RefineNet-R101", "DCNN-R152", "ACNet-R50", "SAGate-R101",
        "ESANet-R34Δ", "CANet-R50", "SGACNet-R34Δ", "PGDENet-R34", "FEAGNet-V1", "FEAGNet-V1*",
        "FEAGNet-V2", "FEAGNet-V2*"]
    assert labels["table2"] == [
        "DABNet", "SwiftNet", "LDN", "DDRNet-S", "PIDNet-S", "FEAGNet-S", "FEAGNet-S*",
        "FEAGNet-L", "FEAGNet-L*", "SSMA", "LDFNet", "ESANet-R34Δ", "SGACNet-R34Δ",
        "FEAGNet-V1", "FEAGNet-V1*", "FEAGNet-V2", "FEAGNet-V2*"]
    assert labels["table4"] == ["ORGBMap", "TESAMap", "TFEAGMap", "MESAMap", "MVSMMap"]


def _clean(field: str) -> str:
    return re.sub(r"<[^>]+>|\s|†", "", field)


def _is_data(fields: list[str]) -> bool:
    cleaned = [_clean(f) for f in fields]
    return any(cleaned) and all(re.fullmatch(r"\d+(\.\d+)?|-|√|", c) for c in cleaned)


def test_every_printed_number_matches_the_paper(tables):
    """Each table's rows in the paper's markdown, number by number, against the file."""
    if not PAPER.is_file():
        missing(f"{PAPER} not found: the paper's text is in ../shared/paper beside the checkout")
    text = PAPER.read_text(encoding="utf-8")
    starts = {"table1": "TABLE I:", "table2": "TABLE II:", "table3": "TABLE III:",
              "table4": "TABLE IV:"}
    for tid, marker in starts.items():
        t = tables[tid]
        lines = [ln.split("\t") for ln in text[text.index(marker):].splitlines() if "\t" in ln]
        if tid == "table3":  # no label column: five check-mark columns, then three numbers
            data = [f for f in lines if _is_data(f)][: len(t.rows)]
        else:
            data = [f for f in lines if _is_data(f[1:])][: len(t.rows)]
        assert len(data) == len(t.rows), tid
        for system, fields in zip(t.rows, data, strict=True):
            if tid != "table3":
                assert _clean(fields[0]).startswith(_clean(system.label).rstrip("*Δ")[:5]), \
                    (tid, system.id, fields[0])
                fields = fields[1:]
            printed = [_clean(f) for f in fields]
            got = [_clean(t.cell(system.id, c.id).printed) for c in t.columns]
            assert got == printed, (tid, system.id)
            bold = ["<b>" in f for f in fields]
            assert bold == [t.cell(system.id, c.id).bold for c in t.columns], (tid, system.id)
            dagger = ["†" in f for f in fields]
            assert dagger == ["†" in t.cell(system.id, c.id).marks for c in t.columns], \
                (tid, system.id)


# ---------------------------------------------------------------------------- values
@pytest.mark.parametrize("tid,row,col,printed,value,extra", [
    ("table1", "feagnet-v2", "params", "4.5", 4.5e6, {}),
    ("table1", "feagnet-v1", "flops", "1.9", 1.9e9, {}),
    ("table1", "pgdenet-r34", "miou_nyuv2", "53.7", 0.537, {"bold": True}),
    ("table1", "rdfnet-r101", "fps", "7.9†", 7.9, {"marks": ("†",)}),
    ("table1", "dcnn-r152", "params", "92.0", 92.0e6, {"decimals": 1}),
    ("table1", "feagnet-v1-jetson", "fps", "54.8", 54.8,
     {"bold": True, "hardware": "jetson-tensorrt"}),
    ("table2", "ddrnet-s", "fps_1024", "108†", 108.0, {"decimals": 0}),
    ("table2", "ddrnet-s", "fps_2048", "60.6†", 60.6, {"bold": True}),
    ("table2", "feagnet-l", "miou_2048", "77.3", 0.773, {}),
    ("table2", "esanet-r34", "miou_1024", "75.2", 0.752, {"bold": True}),
    ("table3", "basel", "miou", "44.35", 0.4435, {"decimals": 2}),
    ("table3", "basel-dappf", "params", "3.70", 3.70e6, {"decimals": 2}),
    ("table3", "full", "flops", "7.85", 7.85e9, {}),
    ("table4", "evsmap", "runtime", "14.4", 14.4, {}),
    ("table4", "orgbmap", "size_seq5", "40.32", 40.32e6, {}),
    ("table4", "evsmap", "size_seq1", "5.30", 5.30e6, {"decimals": 2}),
])
def test_spot_values(tables, tid, row, col, printed, value, extra):
    cell = tables[tid].cell(row, col)
    assert cell.printed == printed
    assert cell.value == pytest.approx(value)
    for k, v in extra.items():
        assert getattr(cell, k) == v, k


def test_blank_cells(tables):
    t1, t2 = tables["table1"], tables["table2"]
    blank = {(tid, r, c) for tid, t in tables.items() for (r, c), cell in t.cells.items()
             if cell.blank}
    assert ("table1", "3dgnn-r101", "flops") in blank
    assert ("table2", "ssma", "fps_2048") in blank
    assert t1.cell("rdfnet-r101", "miou_sunrgbd").value is None
    assert t2.cell("ldn", "fps_1024").text == "-"
    # Table I: 3DGNN flops, RDFNet/DCNN/SAGate SUN RGBD, DCNN flops. Table II: DABNet 1,
    # LDN 2, DDRNet-S 1, PIDNet-S 1, SSMA 3, LDFNet 3.
    assert sum(1 for b in blank if b[0] == "table1") == 5
    assert sum(1 for b in blank if b[0] == "table2") == 11
    assert not any(b[0] in ("table3", "table4") for b in blank)


def test_bold_cells_as_printed(tables):
    bold = sorted((tid, r, c) for tid, t in tables.items() for (r, c), cell in t.cells.items()
                  if cell.bold)
    assert bold == sorted([
        ("table1", "pgdenet-r34", "miou_nyuv2"), ("table1", "pgdenet-r34", "miou_sunrgbd"),
        ("table1", "feagnet-v1-jetson", "flops"), ("table1", "feagnet-v1-jetson", "fps"),
        ("table1", "feagnet-v2-jetson", "params"),
        ("table2", "dabnet", "params"), ("table2", "swiftnet", "fps_1024"),
        ("table2", "ddrnet-s", "fps_2048"), ("table2", "ssma", "miou_2048"),
        ("table2", "esanet-r34", "miou_1024")])


def test_star_rows_are_timed_on_the_jetson(tables):
    for tid in ("table1", "table2"):
        t = tables[tid]
        for system in t.rows:
            for col in t.columns:
                hw = t.cell(system.id, col.id).hardware
                expected = "jetson-tensorrt" if system.label.endswith("*") and col.timing else None
                assert hw == expected, (tid, system.id, col.id)


def test_cell_text(tables):
    t1 = tables["table1"]
    assert t1.cell("feagnet-v2", "params").text == "4.5M"
    assert t1.cell("feagnet-v2", "flops").text == "7.8G"
    assert t1.cell("feagnet-v2", "miou_nyuv2").text == "47.6%"
    assert tables["table4"].cell("evsmap", "size_seq2").text == "15.34 MB"
    assert tables["table3"].cell("basel", "cfim").printed == ""
    assert tables["table3"].cell("basel", "basel").value == 1.0


# ---------------------------------------------------------------------------- systems
def test_systems_match_the_registry(tables):
    from evsmap.registry import SEGMENTERS, UPDATERS

    for t in tables.values():
        for s in t.rows:
            if not s.implemented:
                assert s.segmenter is None and s.updater is None
                continue
            for comp, registry in ((s.segmenter, SEGMENTERS), (s.updater, UPDATERS)):
                if comp is None:
                    continue
                params = registry.get(comp.name).options
                assert set(comp.config) <= set(params), (t.id, s.id)
            if s.segmenter is not None:
                params = SEGMENTERS.get(s.segmenter.name).options
                for dataset in ("nyuv2", "sunrgbd", "cityscapes"):
                    resolved = s.segmenter_for(dataset)
                    assert resolved.name == s.segmenter.name, (t.id, s.id, dataset)
                    assert set(resolved.config) <= set(params), (t.id, s.id, dataset)


def test_table3_flags_match_the_ablation_switches(tables):
    from evsmap.models.feagnet import ABLATIONS

    t = tables["table3"]
    to_option = {"cfim": "cfim", "dappf": "dappf", "waha": "attention", "ml": "multiscale"}
    assert [s.ablation for s in t.rows] == list(ABLATIONS)
    for s in t.rows:
        assert s.segmenter.name == "feagnet-v2"
        assert s.segmenter.config == ABLATIONS[s.ablation]
        for col, option in to_option.items():
            assert (t.cell(s.id, col).value == 1.0) == s.segmenter.config[option], (s.id, col)


def test_table4_systems(tables):
    t = tables["table4"]
    pairs = {s.id: (s.segmenter and s.segmenter.name, s.updater.name) for s in t.rows}
    assert pairs == {
        "orgbmap": (None, "orgb"),
        "tesamap": ("esanet-r34-nbt1d", "classic-semantic"),
        "tfeagmap": ("feagnet-v2", "classic-semantic"),
        "mesamap": ("esanet-r34-nbt1d", "multiclass-bayes"),
        "evsmap": ("feagnet-v2", "multiclass-bayes"),
    }
    assert "MVSMMap" in t.row("evsmap").note or "EVSMap" in t.row("evsmap").note


def test_hardware_and_datasets_declared():
    f = load_file()
    assert "jetson-tensorrt" in f.hardware
    assert {"nyuv2", "sunrgbd", "cityscapes", "tum", "rtabmap", "asl", "ours1",
            "ours2"} <= set(f.datasets)


# ---------------------------------------------------------------------------- schema errors
def _broken(raw, edit):
    data = copy.deepcopy(raw)
    edit(data)
    return data


@pytest.mark.parametrize("edit,message", [
    (lambda d: d["tables"]["table1"].update(colour="red"),
     r"table table1: unknown key\(s\) 'colour'"),
    (lambda d: d["tables"]["table1"]["rows"][0]["cells"].update(speed="3"),
     r"table table1, row '3dgnn-r101', column 'speed': no such column"),
    (lambda d: d["tables"]["table1"]["rows"][0]["cells"].update(fps="fast"),
     r"table table1, row '3dgnn-r101', column 'fps': 'fast' is not a number"),
    (lambda d: d["tables"]["table1"]["rows"][0]["cells"].pop("params"),
     r"table table1, row '3dgnn-r101', column 'params': cell missing"),
    (lambda d: d["tables"]["table2"]["rows"][0]["cells"].update(params={"printed": "1",
                                                                          "colour": "x"}),
     r"table table2, row 'dabnet', column 'params': unknown key\(s\) 'colour'"),
    (lambda d: d["tables"]["table1"]["rows"][0]["cells"].update(
        fps={"printed": "4.8", "hardware": "toaster"}),
     r"column 'fps': unknown hardware 'toaster'"),
    (lambda d: d["tables"]["table1"]["rows"][0]["cells"].update(
        params={"printed": "47.3", "hardware": "jetson-tensorrt"}),
     r"column 'params': hardware applies to timing columns only"),
    (lambda d: d["tables"]["table1"]["columns"][0].update(unit="M"),
     r"table table1, column 'miou_nyuv2': unit 'M' does not fit quantity 'miou'"),
    (lambda d: d["tables"]["table1"]["columns"][0].update(dataset="imagenet"),
     r"column 'miou_nyuv2': unknown dataset 'imagenet'"),
    (lambda d: d["tables"]["table3"]["rows"][0]["cells"].update(cfim="x"),
     r"table table3, row 'basel', column 'cfim': a flag cell"),
    (lambda d: d["tables"]["table1"]["rows"][1].update(id="3dgnn-r101"),
     r"row id '3dgnn-r101' appears twice"),
    (lambda d: d["tables"]["table4"]["rows"][0].pop("updater"),
     r"table table4, row 'orgbmap': an implemented row needs a segmenter or an updater"),
    (lambda d: d.update(schema_version=2), r"schema_version must be 1"),
])
def test_schema_errors_name_the_place(raw, edit, message):
    with pytest.raises(TableSchemaError, match=message):
        parse_tables(_broken(raw, edit))


def test_unreadable_file(tmp_path):
    bad = tmp_path / "t.toml"
    bad.write_text("tables = [")
    with pytest.raises(TableSchemaError, match="not valid TOML"):
        load_tables(bad)
    with pytest.raises(TableSchemaError, match="cannot read"):
        load_tables(tmp_path / "missing.toml")


def test_a_table_file_with_the_old_name_of_the_leaf_size_loads(raw, tmp_path):
    """Until issue 55 a mapping column's leaf size was ``voxel_size`` (and
    ``voxel_size_source``): a user's table file written so reads as ``resolution``."""
    old = copy.deepcopy(raw)
    for col in old["tables"]["table4"]["columns"]:
        col["voxel_size"], col["voxel_size_source"] = (col.pop("resolution"),
                                                       col.pop("resolution_source"))
    columns = parse_tables(old).tables["table4"].columns
    assert columns == parse_tables(raw).tables["table4"].columns
    assert {(c.resolution, c.resolution_source) for c in columns} == {(0.02, "assumed")}
    path = tmp_path / "mine.toml"
    path.write_text(default_path().read_text()
                     .replace("resolution = 0.02", "voxel_size = 0.02")
                     .replace("resolution_source =", "voxel_size_source ="))
    assert [c.key for c in expand_all(load_tables(path))] == [
        c.key for c in expand_all(load_tables())]


def test_the_leaf_size_and_its_source_go_together(raw):
    broken = _broken(raw, lambda d: d["tables"]["table4"]["columns"][0].pop("resolution_source"))
    with pytest.raises(TableSchemaError, match="give resolution_source exactly when resolution"):
        parse_tables(broken)


# ---------------------------------------------------------------------------- expansion
def test_expansion_is_deterministic_and_keys_unique(tables):
    a, b = expand_all(tables), expand_all(load_tables())
    assert [c.key for c in a] == [c.key for c in b]
    assert a == b
    keys = [c.key for c in a]
    assert len(keys) == len(set(keys))


def test_expansion_of_table1(tables):
    specs = expand(tables["table1"])
    rows = {c.row for c in specs}
    # every row is implemented (the comparison networks of baselines.networks, issue 19)
    assert rows == {r.id for r in tables["table1"].rows if r.implemented} == {
        r.id for r in tables["table1"].rows}
    assert {"acnet-r50", "refinenet-r101", "3dgnn-r101", "pgdenet-r34"} <= rows
    by_key = {c.key: c for c in specs}
    acc = by_key["table1/feagnet-v2/accuracy/nyuv2:test[miou]"]
    assert acc.metrics == ("miou_nyuv2",) and acc.split == "test"
    assert acc.requires == ("dataset:nyuv2", "weights:feagnet-v2@nyuv2") == acc.needs
    assert not acc.fresh_process
    sun = by_key["table1/feagnet-v2/accuracy/sunrgbd:test[miou]"]
    assert sun.segmenter.config == {"num_classes": 37}
    comp = by_key["table1/feagnet-v2/complexity@640x480[params,flops]"]
    assert comp.metrics == ("params", "flops") and comp.requires == ()
    assert comp.input_size == (480, 640) and comp.printed_size == "640x480"
    assert [c.printed for c in comp.paper] == ["4.5", "7.8"]
    fast = by_key["table1/feagnet-v2-jetson/speed@640x480#jetson-tensorrt[fps]"]
    assert fast.fresh_process and fast.hardware == "jetson-tensorrt"
    assert fast.needs == ("hardware:jetson-tensorrt",)
    # the starred and unstarred rows share the accuracy run
    assert acc.config_key == by_key["table1/feagnet-v2-jetson/accuracy/nyuv2:test[miou]"
                                    ].config_key


def test_needs_subtract_what_is_available(tables):
    specs = expand(tables["table1"], available=["dataset:nyuv2", "weights:feagnet-v2@nyuv2"])
    acc = next(c for c in specs if c.key == "table1/feagnet-v2/accuracy/nyuv2:test[miou]")
    assert acc.requires == ("dataset:nyuv2", "weights:feagnet-v2@nyuv2") and acc.runnable
    sun = next(c for c in specs if c.key == "table1/feagnet-v2/accuracy/sunrgbd:test[miou]")
    assert sun.needs == ("dataset:sunrgbd", "weights:feagnet-v2(num_classes=37)@sunrgbd")


def test_timing_cells_run_fresh(tables):
    for spec in expand_all(tables):
        quantities = {spec.paper[i].column for i in range(len(spec.paper))}
        timed = any(tables[spec.table].column(c).timing for c in quantities)
        assert spec.fresh_process == timed
        if timed:
            assert len(spec.metrics) == 1


def test_expansion_of_tables_3_and_4(tables):
    t3 = expand(tables["table3"])
    assert len(t3) == 12  # 6 rows x (accuracy, complexity)
    assert t3[0].segmenter.config == {"attention": False, "cfim": False, "dappf": False,
                                      "multiscale": False}
    assert not any(c.kind == "flag" for c in t3)
    t4 = expand(tables["table4"])
    assert len(t4) == 5 * 6  # runtime + 5 map sizes per system
    orgb = [c for c in t4 if c.row == "orgbmap"]
    assert all(c.segmenter is None and c.updater.name == "orgb" for c in orgb)
    assert not any(r.startswith("weights:") for c in orgb for r in c.requires)
    ev = {c.key: c for c in t4 if c.row == "evsmap"}
    size = ev["table4/evsmap/mapping/tum@0.02m[map_size]"]
    assert size.requires == ("dataset:tum", "weights:feagnet-v2@nyuv2")
    assert size.resolution == 0.02 and size.printed_size == "0.02 m" and not size.fresh_process
    runtime = ev["table4/evsmap/mapping/tum+rtabmap+asl+ours1+ours2@0.02m[runtime_hz]"]
    assert runtime.fresh_process and len(runtime.datasets) == 5
