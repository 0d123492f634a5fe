"""``reproduce --precision int8``: one int8 record per network, side by side with fp32 in the
report."""

from __future__ import annotations

from dataclasses import replace

import pytest

from evsmap.environment import instruction_set
from evsmap.report.int8 import int8_frame, int8_markdown
from evsmap.runner.context import RunContext
from evsmap.runner.int8 import int8_key, network_specs, run_int8
from evsmap.runner.records import RecordStore
from evsmap.segmenters.quantize import auto_scheme
from evsmap.tables.schema import expand, load_tables


@pytest.fixture(scope="module")
def v1_speed():
    specs = [s for s in expand(load_tables()["table1"]) if s.kind == "speed"
             and s.segmenter is not None and s.segmenter.name == "feagnet-v1"]
    return replace(specs[0], input_size=(64, 96), needs=())


def test_one_record_per_network_and_size(v1_speed):
    other = replace(v1_speed, key=v1_speed.key + "-again")
    smaller = replace(v1_speed, key=v1_speed.key + "-small", input_size=(96, 128))
    accuracy = replace(v1_speed, kind="accuracy")
    picked = network_specs([v1_speed, other, smaller, accuracy])
    assert [int8_key(s) for s in picked] == ["extra/int8/feagnet-v1@96x64",
                                             "extra/int8/feagnet-v1@128x96"]


@pytest.mark.isa
def test_the_int8_pass_measures_and_the_report_shows_it(tmp_path, v1_speed):
    ctx = RunContext.create(tmp_path / "run", data_root=tmp_path, quick=True)
    [rec] = run_int8(ctx, [v1_speed], say=lambda *_: None)
    assert rec.status == "ok", rec.error
    v = rec.values
    assert v["fp32_ms"] > 0 and v["int8_ms"] > 0
    assert v["speedup"] == pytest.approx(v["fp32_ms"] / v["int8_ms"])
    assert 0.0 <= v["agreement"] <= 1.0
    assert "miou_int8" not in v  # untrained, no dataset: no mIoU
    assert rec.details["quantization"]["precision"] == "int8"
    isa = instruction_set()
    assert rec.details["quantization"]["int8_scheme"] == auto_scheme()
    assert rec.details["quantization"]["instruction_set"] == isa
    assert rec.inputs["table"] == "table1"
    # stored, and kept on resume
    assert RecordStore(ctx.out).get(rec.key) is not None
    [again] = run_int8(ctx, [v1_speed], resume=True, say=lambda *_: None)
    assert again.started == rec.started
    md = "\n".join(int8_markdown([rec], "table1"))
    assert "int8 beside fp32" in md and f"| {rec.label} | 96x64 |" in md
    assert "needs weights" in md
    assert int8_markdown([rec], "table2") == []
    frame = int8_frame([rec])
    assert list(frame["input"]) == ["96x64"] and frame["speedup"].iloc[0] > 0
    assert (frame["scheme"].iloc[0], frame["instruction_set"].iloc[0]) == (auto_scheme(), isa)
    assert f"| {auto_scheme()} (auto for {isa}) |" in md
