"""``reproduce --precision int8`` with Table IV: EVSMap end to end with each post-processing
path, one record per network, and its section after Table IV."""

from __future__ import annotations

import pytest

from evsmap.environment import instruction_set
from evsmap.report.realtime import realtime_markdown
from evsmap.runner import realtime
from evsmap.runner.context import RunContext
from evsmap.runner.records import CellRecord, RecordStore


@pytest.mark.isa
def test_the_realtime_pass_measures_every_path_and_the_report_shows_it(tmp_path, monkeypatch):
    monkeypatch.setattr(realtime, "NETWORKS", ("feagnet-v1",))
    monkeypatch.setattr(realtime, "INPUT_SIZE", (64, 96))
    ctx = RunContext.create(tmp_path / "run", data_root=tmp_path, quick=True)
    ctx.frames = 3
    [rec] = realtime.run_realtime(ctx, say=lambda *_: None)
    assert rec.status == "ok", rec.error
    assert rec.key == "extra/realtime/feagnet-v1@synthetic"
    assert set(rec.values) == {"wall_hz_network", "wall_hz_fused", "wall_hz_stride"}
    assert all(v > 0 for v in rec.values.values())
    runs = rec.details["runs"]
    assert all(len(runs[p]) == 1 for p in ("network", "fused", "stride"))  # --quick: 1 round
    assert rec.details["instruction_set"] == instruction_set()
    assert RecordStore(ctx.out).get(rec.key) is not None
    [again] = realtime.run_realtime(ctx, resume=True, say=lambda *_: None)
    assert again.started == rec.started
    md = "\n".join(realtime_markdown([rec]))
    assert "the faithful path and its variants" in md
    assert f"| feagnet-v1 | {rec.values['wall_hz_network']:.2f} |" in md
    assert f"| 30 | {instruction_set()}, " in md


def test_a_failed_network_is_one_row_saying_why():
    rec = CellRecord(key="extra/realtime/feagnet-v2@synthetic", table="extra",
                     row="realtime-feagnet-v2", label="x", kind="mapping", metrics=[],
                     inputs={"segmenter": "feagnet-v2"}, status="error", error="no onnxruntime")
    md = realtime_markdown([rec])
    assert any(line.startswith("| feagnet-v2 | error: no onnxruntime |") for line in md)
    assert realtime_markdown([]) == []
