"""A mapping run that two rows name (Table IV's and the semantic-detail section's, with the
oracle's labels for both) is mapped once and its record copied to the other row."""

from __future__ import annotations

import numpy as np
import pytest

from evsmap.runner import matrix
from evsmap.runner.context import RunContext
from evsmap.runner.mapping_dedup import SAME_RUN_NOTE, copied_record, run_identity, same_runs
from evsmap.runner.records import CellRecord
from tests.runner.runner_fixtures import Inline


@pytest.fixture
def ctx(tmp_path):
    empty = tmp_path / "data"
    empty.mkdir()
    return RunContext.create(tmp_path / "run", data_root=empty)


def _synthetic_runs(ctx):
    plan = matrix.plan(ctx, ["table4"])
    return [r for r in plan.runs if r.sequence == "synthetic"]


def test_the_detail_rows_that_are_table_iv_runs_are_mapped_once(ctx):
    runs = _synthetic_runs(ctx)
    to_map, copies = same_runs(runs)
    by_row = {r.row: r for r in runs}
    assert run_identity(by_row["detail-orgbmap"]) == run_identity(by_row["orgbmap"])
    assert run_identity(by_row["detail-evsmap"]) == run_identity(by_row["evsmap"])
    assert run_identity(by_row["evsmap"]) != run_identity(by_row["mesamap"])  # its own network
    copied = {r.row for group in copies.values() for r in group}
    assert {"detail-orgbmap", "detail-evsmap"} <= copied
    assert len(to_map) + len(copied) == len(runs)
    assert not copied & {r.row for r in to_map}
    assert [r.key for r in to_map] == [r.key for r in runs if r.row not in copied]  # in order


def test_runs_with_other_labels_stay_apart(ctx):
    runs = _synthetic_runs(ctx)
    rows = {r.row for r in same_runs(runs)[0]}
    assert {r.row for r in runs if r.row.startswith("detail-labels-")} <= rows


def test_a_copy_is_the_first_runs_record_under_its_own_key(ctx, tmp_path):
    by_row = {r.row: r for r in _synthetic_runs(ctx)}
    first, other = by_row["evsmap"], by_row["detail-evsmap"]
    record = CellRecord(**first.base_fields(), status="ok", values={"leaves": 5.0},
                        notes=["n"], details={"leaves": 5}, seconds=31.0,
                        around={"wall_s": 33.0})
    artifacts = tmp_path / "run" / "artifacts"
    artifacts.mkdir(parents=True)
    np.savez_compressed(artifacts / f"map-evsmap-{first.sequence}.npz", centres=np.zeros(3))
    copy = copied_record(record, first, other, tmp_path / "run")
    assert (copy.key, copy.row, copy.label) == (other.key, other.row, other.label)
    assert copy.values == record.values and copy.details["same_run_as"] == first.key
    assert copy.notes[-1] == SAME_RUN_NOTE.format(key=first.key)
    assert copy.seconds == 0.0 and copy.around == {"wall_s": 0.0}
    assert record.key == first.key and record.notes == ["n"]  # the first's record untouched
    copied = artifacts / f"map-detail-evsmap-{first.sequence}.npz"
    assert copied.read_bytes() == (artifacts / f"map-evsmap-{first.sequence}.npz").read_bytes()


def test_the_runner_maps_a_shared_run_once_and_keeps_every_rows_record(ctx, monkeypatch):
    mapped: list[str] = []

    def execute_mapping(run, run_ctx):
        mapped.append(run.key)
        return CellRecord(**run.base_fields(), status="ok", seconds=1.0,
                          values={"leaves": 1.0, "segment_update_hz": 2.0, "map_bytes": 9.0})

    def execute_spec(spec, run_ctx):
        return CellRecord(key=spec.key, table=spec.table, row=spec.row, label=spec.label,
                          kind=spec.kind, metrics=list(spec.metrics), status="na",
                          reason="n/a - test")

    monkeypatch.setattr(matrix, "execute_mapping", execute_mapping)
    monkeypatch.setattr(matrix, "execute_spec", execute_spec)
    monkeypatch.setattr(matrix, "lacks_labels", lambda *a, **k: False)
    plan = matrix.plan(ctx, ["table4"])
    synthetic = [r for r in plan.runs if r.sequence == "synthetic"]
    plan.runs = synthetic
    records = {r.key: r for r in matrix.run_matrix(ctx, plan, pool=lambda n: Inline(),
                                                    fresh=Inline)}
    keys = {r.key for r in synthetic}
    assert keys <= set(records)
    assert len(mapped) == len(set(mapped)) == len(same_runs(synthetic)[0]) < len(synthetic)
    detail = next(r for r in synthetic if r.row == "detail-evsmap")
    assert detail.key not in mapped and records[detail.key].status == "ok"
