"""``run.json`` is one model (:class:`evsmap.runner.runfile.RunFile`): a file written by an
earlier version loads, one written here round-trips key for key, and a broken one is one line
naming the file."""

from __future__ import annotations

import json

import pytest

from evsmap.errors import DataFormatError
from evsmap.runner.runfile import RunFile, RunSettings
from evsmap.tables.schema import table_ids


def test_a_file_without_settings_or_tables_keeps_its_quick(tmp_path):
    path = tmp_path / "run.json"
    path.write_text(json.dumps({"quick": True, "cells": ["a"], "unknown": 1}))
    run = RunFile.read(path)
    assert run.stored_settings() == {"quick": True}
    assert run.tables == list(table_ids()) and run.cells == ["a"]


def test_written_keys_round_trip(tmp_path):
    path = tmp_path / "run.json"
    settings = RunSettings(quick=True, workers=1, data_root=tmp_path)
    RunFile(tables=["table4"], cells=["x"], skipped=[("y", "why")], run="r",
            settings=settings).write(path)
    data = json.loads(path.read_text())
    assert list(data)[:3] == ["tables", "quick", "data_root"]
    assert "executor" not in data and "train" not in data and data["finished"] is None
    assert data["settings"]["data_root"] == str(tmp_path) and data["skipped"] == [["y", "why"]]
    again = RunFile.read(path)
    assert again.settings is not None and again.settings.data_root == tmp_path
    assert set(again.stored_settings()) == set(RunSettings.model_fields)
    again.write(tmp_path / "again.json")
    assert json.loads((tmp_path / "again.json").read_text()) == data


@pytest.mark.parametrize(("text", "words"), [
    ("[1]", "expected a JSON object"),
    ("{", "unreadable run description"),
    ('{"cells": "all"}', "cells: Input should be a valid list"),
    ('{"settings": {"precision": "fp16"}}', "settings.precision"),
])
def test_a_broken_file_is_one_line_naming_it(tmp_path, text, words):
    path = tmp_path / "run.json"
    path.write_text(text)
    with pytest.raises(DataFormatError) as info:
        RunFile.read(path)
    message = str(info.value)
    assert message.startswith(f"{path}: ") and words in message and "\n" not in message
