"""Schema errors are one line: the file, the place in the tables' words, what is wrong; never
pydantic's multi-line report."""

from __future__ import annotations

import copy
import tomllib

import pytest

from evsmap.tables import TableSchemaError, load_tables
from evsmap.tables.schema import default_path, parse_tables


@pytest.fixture(scope="module")
def raw():
    with open(default_path(), "rb") as f:
        return tomllib.load(f)


def _error(raw, edit) -> str:
    data = copy.deepcopy(raw)
    edit(data)
    with pytest.raises(TableSchemaError) as info:
        parse_tables(data, source="paper_tables.toml")
    message = str(info.value)
    assert "\n" not in message and message.startswith("paper_tables.toml: ")
    assert "errors.pydantic.dev" not in message
    return message


@pytest.mark.parametrize("edit,expected", [
    (lambda d: d["tables"]["table1"]["rows"][0].update(year="2017"),
     "paper_tables.toml: table table1, row '3dgnn-r101': year: Input should be a valid integer, "
     "got '2017'"),
    (lambda d: d["tables"]["table1"]["rows"][0].pop("label"),
     "paper_tables.toml: table table1, row '3dgnn-r101': missing 'label'"),
    (lambda d: d["tables"]["table1"]["rows"][0].update(implemented="yes"),
     "paper_tables.toml: table table1, row '3dgnn-r101': implemented: Input should be a valid "
     "boolean, got 'yes'"),
    (lambda d: d["tables"]["table1"]["columns"][3].update(input_size=[480]),
     "paper_tables.toml: table table1, column 'flops': input_size: expected [height, width], "
     "got [480]"),
    (lambda d: d["tables"]["table1"]["columns"][3].update(input_size=[480, 0]),
     "paper_tables.toml: table table1, column 'flops': input_size.1: Input should be greater "
     "than 0, got 0"),
    (lambda d: d["tables"]["table1"]["columns"][3].pop("input_size_source"),
     "paper_tables.toml: table table1, column 'flops': give input_size_source exactly when "
     "input_size is given"),
    (lambda d: d["tables"]["table1"]["rows"][0]["cells"].update(fps=4.8),
     "paper_tables.toml: table table1, row '3dgnn-r101', column 'fps': a cell is a printed "
     "string or an inline table, got 4.8"),
    (lambda d: d["tables"]["table1"]["rows"][0]["cells"].update(fps="4.8‡"),
     "paper_tables.toml: table table1, row '3dgnn-r101', column 'fps': '4.8‡' is not a number "
     "(write \"-\" for a blank cell)"),
    (lambda d: d["tables"]["table1"]["rows"][0].update(id="3DGNN"),
     "paper_tables.toml: table table1, row '3DGNN': id: ids are lower case letters, digits and "
     "_.+- (got '3DGNN')"),
    (lambda d: d["hardware"]["jetson-tensorrt"].update(watts=30),
     "paper_tables.toml: hardware 'jetson-tensorrt': unknown key(s) 'watts' (allowed: "
     "description, note)"),
    (lambda d: d.update(colour="red", size=3),
     "paper_tables.toml: unknown key(s) 'colour', 'size' (allowed: datasets, hardware, "
     "schema_version, source, tables)"),
    (lambda d: d["tables"]["table2"]["rows"][5]["segmenter"].update(weights="x.pt"),
     "paper_tables.toml: table table2, row 'feagnet-s': segmenter: unknown key(s) 'weights' "
     "(allowed: card, name, options)"),
    (lambda d: d["tables"]["table1"].update(rows=[]),
     "paper_tables.toml: table table1: rows: List should have at least 1 item after "
     "validation, not 0, got []"),
    (lambda d: d["tables"]["table1"]["columns"][1].update(id="miou_nyuv2"),
     "paper_tables.toml: table table1: column id 'miou_nyuv2' appears twice"),
])
def test_messages(raw, edit, expected):
    assert _error(raw, edit) == expected


def test_more_errors_are_counted(raw):
    def edit(d):
        d["tables"]["table1"]["rows"][0].update(year="2017", label=3)

    assert _error(raw, edit).endswith("(and 1 more error)")


def test_a_file_names_itself(tmp_path):
    text = default_path().read_text(encoding="utf-8").replace('schema_version = 1',
                                                              'schema_version = 3')
    path = tmp_path / "tables.toml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(TableSchemaError, match=rf"^{path}: schema_version must be 1, got 3$"):
        load_tables(path)


def test_the_file_loads_without_the_registries():
    import subprocess
    import sys

    code = ("import sys; from evsmap.tables import load_tables; load_tables(); "
            "print(any(m.startswith(('evsmap.registry', 'torch', 'baselines')) "
            "for m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


# the tables' rules (role, baseline, claims) are validated like the rest of the file
def _second_mapping(d):
    d["tables"]["table2"]["role"] = "mapping"


def test_rules_that_name_nothing_are_one_line(raw):
    assert "baseline 'nope' is not a row" in _error(
        raw, lambda d: d["tables"]["table1"].update(baseline="nope"))
    assert "no such column 'fast'" in _error(
        raw, lambda d: d["tables"]["table1"]["claims"][0].update(column="fast"))
    assert "a claim needs the table's baseline" in _error(
        raw, lambda d: d["tables"]["table1"].pop("baseline"))
    assert "only one table may have role 'mapping'" in _error(raw, _second_mapping)
    assert "role" in _error(raw, lambda d: d["tables"]["table1"].update(role="maps"))
