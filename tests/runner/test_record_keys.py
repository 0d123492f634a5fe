"""Records written before the rates had one name each still load: their old keys are read under
the new names (``evsmap.runner.record_keys.OLD_KEYS``), so a stored run rebuilds the same tables."""

from __future__ import annotations

import json

from evsmap.runner.record_keys import OLD_KEYS, renamed_keys
from evsmap.runner.records import CellRecord, RecordStore


def _old_mapping_record() -> dict:
    """A mapping run's record as ``main`` wrote it before the rename (issue 37)."""
    values = {"frames": 8.0, "update_hz": 40.0, "end_to_end_hz": 12.5, "map_bytes": 2.0e5}
    return {"key": "extra/mapping/evsmap/synthetic@0.02m", "table": "extra", "row": "evsmap",
            "label": "EVSMap", "kind": "mapping", "metrics": [], "status": "ok",
            "values": values, "details": {"update_ms": [25.0], "segment_ms": [55.0], **values},
            "inputs": {"sequence": "synthetic", "voxel_size": 0.02}}


def test_the_old_keys_name_one_quantity_each():
    assert OLD_KEYS == {"hz_median": "update_hz", "hz_segment_update": "segment_update_hz",
                        "hz_end_to_end": "wall_hz", "end_to_end_hz": "segment_update_hz",
                        "voxel_size": "resolution"}
    # ``map --json``'s old record: every rate under its new name, the other keys kept in order
    old = {"frames": 2, "hz_median": 50.0, "hz_end_to_end": 9.0, "hz_segment_update": 20.0,
           "wall_s": 0.2}
    assert list(renamed_keys(old).items()) == [
        ("frames", 2), ("update_hz", 50.0), ("wall_hz", 9.0), ("segment_update_hz", 20.0),
        ("wall_s", 0.2)]
    # a key already under its new name wins over its old name
    assert renamed_keys({"segment_update_hz": 1.0, "end_to_end_hz": 2.0}) == {
        "segment_update_hz": 1.0}


def test_a_stored_record_with_the_old_keys_loads_under_the_new_ones(tmp_path):
    store = RecordStore(tmp_path)
    data = _old_mapping_record()
    store.folder.mkdir(parents=True)
    store.path(data["key"]).write_text(json.dumps(data))
    rec = store.get(data["key"])
    assert rec is not None
    assert rec.values == {"frames": 8.0, "update_hz": 40.0, "segment_update_hz": 12.5,
                          "map_bytes": 2.0e5, "map_bytes_message": 2.0e5}
    assert rec.details["segment_update_hz"] == 12.5 and "end_to_end_hz" not in rec.details
    # the leaf size, ``voxel_size`` in the inputs before issue 55, reads as ``resolution``
    assert rec.inputs == {"sequence": "synthetic", "resolution": 0.02}


def test_an_old_run_fills_the_tables_as_before(tmp_path):
    from evsmap.report.tables import extra_frame

    rec = CellRecord.from_json(_old_mapping_record(), source="old.json")
    row = extra_frame([rec]).iloc[0]
    assert row["update_hz"] == 40.0 and row["segment_update_hz"] == 12.5
    assert row["resolution"] == 0.02 and row["sequence"] == "synthetic"


def test_an_old_ssmi_record_reads_its_saved_file_and_its_message():
    """Before 2026-11-28 ``map_bytes`` of multiclass-bayes on SSMI's generator was its
    octomap_full message (36 B a node); the file SSMI saves is its colour-only ColorOcTree."""
    data = _old_mapping_record()
    data["values"].update(map_bytes=9.0e5, map_bytes_colour=2.0e5)
    data["inputs"]["updater"] = "multiclass-bayes"
    data["details"]["front_end"] = {"name": "generator"}
    rec = CellRecord.from_json(data, source="old.json")
    assert rec.values["map_bytes"] == 2.0e5 and rec.values["map_bytes_message"] == 9.0e5
    # the direct front end (or a record from before the front end was recorded) saved its file
    data["details"]["front_end"] = {"name": "direct"}
    rec = CellRecord.from_json(data, source="old.json")
    assert rec.values["map_bytes"] == 9.0e5 == rec.values["map_bytes_message"]
    # a record of today is read as written
    data["values"].update(map_bytes=2.0e5, map_bytes_message=9.0e5)
    data["details"]["front_end"] = {"name": "generator"}
    assert CellRecord.from_json(data, source="new.json").values["map_bytes_message"] == 9.0e5
