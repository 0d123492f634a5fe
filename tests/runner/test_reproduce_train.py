"""``evsmap reproduce --train``: proxy weights trained on a tiny synthrooms (``--quick``), their
test mIoU recorded as the card's, the "Synthetic proxy" sections of Tables I and IV, the two
proxy maps scored against the room's ground truth, and a resumed run that does not retrain.

The paper's cells are faked (in-process, instant): only the proxy part runs for real."""

from __future__ import annotations

import json
import math

import pandas as pd
import pytest
from runner_fixtures import Inline

import evsmap.runner.mapping_labels as mapping_labels
import evsmap.runner.matrix as matrix
from evsmap.cli.main import main
from evsmap.runner.records import CellRecord
from evsmap.segmenters.cards import inspect_weights


@pytest.fixture
def fake_cells(monkeypatch):
    def execute_spec(spec, ctx):
        return CellRecord(key=spec.key, table=spec.table, row=spec.row, label=spec.label,
                          kind=spec.kind, metrics=list(spec.metrics), status="ok",
                          values={m: 1.0 for m in spec.metrics})

    def execute_mapping(run, ctx):
        return CellRecord(key=run.key, table="extra", row=run.row, label=run.label,
                          kind="mapping", metrics=[], status="ok",
                          values={"segment_update_hz": 1.0, "update_hz": 1.0, "map_bytes": 1.0},
                          inputs={"sequence": run.sequence, "resolution": run.resolution})

    monkeypatch.setattr(matrix, "execute_spec", execute_spec)
    monkeypatch.setattr(matrix, "execute_mapping", execute_mapping)
    monkeypatch.setattr(matrix, "_spawn_pool", Inline)
    monkeypatch.setattr(matrix, "_fresh_executor", Inline)
    monkeypatch.setattr(mapping_labels, "_unlabelled", lambda *a: False)


def _records(out):
    return {r["key"]: r for r in (json.loads(p.read_text())
                                  for p in (out / "records").glob("*.json"))}


def test_reproduce_train_quick(capsys, tmp_path, fake_cells):
    data, weights, out = tmp_path / "data", tmp_path / "weights", tmp_path / "run"
    data.mkdir()
    weights.mkdir()
    argv = ["reproduce", "--quick", "--tables", "I,IV", "--train", "--proxy-models",
            "feagnet-v1", "--data-root", str(data), "--weights-dir", str(weights), "--out",
            str(out)]
    code = main(argv)
    got, err = capsys.readouterr()
    assert code == 0, got + err
    assert "training proxy weights: feagnet-v1 on synthrooms, recipe synth-proxy, 1 epochs" \
        in got
    records = _records(out)
    acc = records["extra/proxy/feagnet-v1/synthrooms"]
    assert acc["status"] == "ok", acc
    best = weights / "proxy" / "feagnet-v1@synthrooms" / "best.pt"
    card = inspect_weights(best).card
    assert math.isfinite(acc["values"]["miou"])
    assert acc["values"]["miou"] == card["test_miou"]  # the card's own test pass
    assert "weights: proxy/feagnet-v1@synthrooms/best.pt (card: feagnet-v1, synthrooms" \
        in acc["notes"][-1]
    room = json.loads((out / "cache" / "synthrooms" / "evsmap-dataset.json").read_text())[
        "split_rooms"]["test"][0]
    for row in ("tfeagmap", "evsmap"):
        rec = records[f"extra/proxy-mapping/{row}/synthrooms-room{room}"]
        assert rec["status"] == "ok", rec
        assert math.isfinite(rec["values"]["semantic_accuracy"])
        assert math.isfinite(rec["values"]["map_miou"])
        assert rec["inputs"]["segmenter"] == "feagnet-v1"
    md1 = (out / "table1.md").read_text()
    section = "Synthetic proxy (evsmap's synthrooms, not the paper's datasets)"
    assert f"## {section}" in md1 and "| feagnet-v1 |" in md1
    md4 = (out / "table4.md").read_text()
    assert f"### {section}" in md4 and "TFEAGMap + proxy feagnet-v1" in md4
    extra = pd.read_csv(out / "extra.csv")
    assert "extra/proxy/feagnet-v1/synthrooms" in set(extra["key"])
    # the paper's cells are untouched by the proxy: no synthrooms value in table1.csv
    assert "synthrooms" not in (out / "table1.csv").read_text()

    # resumed: nothing is trained again
    mtime = best.stat().st_mtime_ns
    code = main(argv[:-2] + ["--out", str(out), "--resume"])
    got, err = capsys.readouterr()
    assert code == 0, got + err
    assert "training proxy weights" not in got
    assert best.stat().st_mtime_ns == mtime
    assert _records(out)["extra/proxy/feagnet-v1/synthrooms"]["values"] == acc["values"]
