"""The matrix runner: planning against what is available, records, resume, configuration
sharing, Table IV from the mapping runs, and the segmentation cache."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from runner_fixtures import Inline

import evsmap.runner.matrix as matrix
from evsmap.runner.context import RunContext
from evsmap.runner.mapping_plan import MappingRun
from evsmap.runner.records import CellRecord, RecordStore, needs_text
from evsmap.runner.table4_reading import table4_record
from evsmap.tables.schema import Component, expand, load_tables


@pytest.fixture
def ctx(tmp_path):
    empty = tmp_path / "data"
    empty.mkdir()
    c = RunContext.create(tmp_path / "run", data_root=empty, quick=True)
    return c


@pytest.fixture
def fake(monkeypatch):
    """Replace the measurements by a counter; a cell whose row is in ``fail`` raises."""
    calls: list[str] = []
    fail: set[str] = set()

    def execute_spec(spec, ctx):
        calls.append(spec.key)
        if spec.row in fail:
            return CellRecord(key=spec.key, table=spec.table, row=spec.row, label=spec.label,
                              kind=spec.kind, metrics=list(spec.metrics), status="error",
                              error="boom")
        return CellRecord(key=spec.key, table=spec.table, row=spec.row, label=spec.label,
                          kind=spec.kind, metrics=list(spec.metrics), status="ok",
                          values={m: float(len(calls)) for m in spec.metrics})

    monkeypatch.setattr(matrix, "execute_spec", execute_spec)
    return calls, fail


def _run(ctx, plan, **kw):
    return matrix.run_matrix(ctx, plan, pool=lambda n: Inline(), fresh=Inline, **kw)


def test_plan_marks_what_is_missing(ctx):
    plan = matrix.plan(ctx, ["table1"])
    by_key = {s.key: s for s in plan.specs}
    acc = by_key["table1/feagnet-v2/accuracy/nyuv2:test[miou]"]
    assert acc.needs == ("dataset:nyuv2", "weights:feagnet-v2@nyuv2")
    assert not by_key["table1/feagnet-v2/complexity@640x480[params,flops]"].needs
    assert by_key["table1/feagnet-v2-jetson/speed@640x480#jetson-tensorrt[fps]"].needs == (
        "hardware:jetson-tensorrt",)
    assert plan.runs == [] and plan.sequences == []


def test_weights_and_datasets_are_found(ctx, tmp_path):
    weights = tmp_path / "w"
    weights.mkdir()
    (weights / "feagnet-v2@nyuv2.pt").write_bytes(b"")
    (weights / "feagnet-v1@sunrgbd.pt").write_bytes(b"")
    ctx.weights_dir = str(weights)
    assert ctx.weights_path("feagnet-v2", "nyuv2").name == "feagnet-v2@nyuv2.pt"
    # options that only adapt the network to the dataset fall back to the plain name
    assert ctx.weights_path("feagnet-v1(num_classes=37)", "sunrgbd") is not None
    assert ctx.weights_path("feagnet-v1", "nyuv2") is None
    assert ctx.available(["weights:feagnet-v2@nyuv2", "dataset:nyuv2",
                          "hardware:jetson-tensorrt"]) == ["weights:feagnet-v2@nyuv2"]


def test_records_na_measured_shared_and_resumed(ctx, fake):
    calls, fail = fake
    plan = matrix.plan(ctx, ["table1"])
    records = _run(ctx, plan)
    assert [r.key for r in records] == plan.keys
    by_key = {r.key: r for r in records}
    na = by_key["table1/feagnet-v2/accuracy/nyuv2:test[miou]"]
    assert na.status == "na" and not na.values
    assert na.reason == needs_text(["dataset:nyuv2", "weights:feagnet-v2@nyuv2"])
    assert "needs the nyuv2 dataset" in na.reason
    # FEAGNet-V2's complexity is one configuration in two rows: measured once, recorded twice
    cx = "complexity@640x480[params,flops]"
    assert sum(k.endswith(cx) and "feagnet-v2" in k for k in calls) == 1
    a, b = by_key[f"table1/feagnet-v2/{cx}"], by_key[f"table1/feagnet-v2-jetson/{cx}"]
    assert a.values == b.values and a.status == b.status == "ok"
    # every record is on disk
    store = RecordStore(ctx.out)
    assert {r.key for r in store} == set(plan.keys)
    # resume: nothing finished runs again; only the n/a cells are reconsidered
    calls.clear()
    _run(ctx, plan, resume=True)
    assert calls == []
    _run(ctx, plan, resume=True, force=True)
    assert len(calls) > 0


def test_a_failing_cell_is_recorded_and_the_run_goes_on(ctx, fake):
    calls, fail = fake
    fail.add("esanet-r34")
    plan = matrix.plan(ctx, ["table1"])
    records = {r.key: r for r in _run(ctx, plan)}
    assert records["table1/esanet-r34/speed@640x480[fps]"].status == "error"
    assert records["table1/feagnet-v1/speed@640x480[fps]"].status == "ok"
    # resume retries the failed cells only
    fail.clear()
    calls.clear()
    _run(ctx, plan, resume=True)
    assert calls and all("esanet-r34" in k for k in calls)


@pytest.mark.parametrize("kind", ["complexity", "mapping"])
def test_a_signal_seen_through_compiled_code_stops_the_run_not_just_the_cell(ctx, monkeypatch,
                                                                             kind):
    # numba and torch hand an exception raised by the signal handler back as a SystemError
    import signal

    import evsmap.runner.execute as execute
    from evsmap.interrupt import Interrupted

    def measured(*args, **kw):
        try:
            raise Interrupted(signal.SIGINT)
        except Interrupted as exc:
            raise SystemError("returned a result with an exception set") from exc

    if kind == "mapping":
        monkeypatch.setattr(execute, "mapping_record", measured)
        run = matrix.plan(ctx, ["table4"]).runs[0]
        with pytest.raises(Interrupted):
            execute.execute_mapping(run, ctx)
    else:
        monkeypatch.setitem(execute.RUNNERS, "complexity", measured)
        spec = next(s for s in matrix.plan(ctx, ["table1"]).specs if s.kind == "complexity")
        with pytest.raises(Interrupted):
            execute.execute_spec(spec, ctx)


def _run_record(row, seq, status="ok", **values):
    return CellRecord(key=f"extra/mapping/{row}/{seq}@0.02m", table="extra", row=row,
                      label=row, kind="mapping", metrics=[], status=status,
                      values=values, notes=[f"{seq} note"], inputs={"sequence": seq},
                      needs=[] if status == "ok" else ["weights:x@nyuv2"],
                      reason="" if status == "ok" else "n/a - needs trained weights (x@nyuv2)")


def test_table4_cells_come_from_the_mapping_runs(ctx):
    specs = {s.key: s for s in expand(load_tables()["table4"])}
    runs = {r.key: r for r in [
        _run_record("evsmap", "synthetic", segment_update_hz=7.5, map_bytes=1e6),
        _run_record("evsmap", "tum", status="na"),
        _run_record("orgbmap", "tum", segment_update_hz=30.0, map_bytes=2e5,
                    octomap_memory_bytes=5e5),
        _run_record("orgbmap", "synthetic", segment_update_hz=25.0, map_bytes=3e5),
    ]}
    rate = table4_record(specs["table4/evsmap/mapping/tum+rtabmap+asl+ours1+ours2@0.02m"
                               "[runtime_hz]"], runs, ctx)
    assert rate.status == "ok" and rate.values == {"runtime": 7.5}
    assert "measured on synthetic" in rate.notes[0]
    size = table4_record(specs["table4/evsmap/mapping/tum@0.02m[map_size]"], runs, ctx)
    assert size.status == "na" and "needs trained weights" in size.reason
    orgb = table4_record(specs["table4/orgbmap/mapping/tum@0.02m[map_size]"], runs, ctx)
    assert orgb.values == {"size_seq1": 5e5}  # read as the C++ memory model
    assert "C++ memory (model)" in orgb.notes[0] and "0.200 MB" in orgb.notes[0]
    orgb_rate = table4_record(specs["table4/orgbmap/mapping/tum+rtabmap+asl+ours1+ours2@0.02m"
                                    "[runtime_hz]"], runs, ctx)
    # like for like: ORGBMap could map TUM but the semantic systems could not, so every
    # row's rate comes from the synthetic room
    assert orgb_rate.values == {"runtime": 25.0}
    assert "measured on synthetic for every row" in orgb_rate.notes[0]
    # once every implemented system maps TUM, TUM is the runtime sequence for all
    from evsmap.runner.table4_reading import runtime_sequence

    rows = [r.id for r in load_tables()["table4"].rows if r.implemented and r.updater]
    all_tum = {f"extra/mapping/{row}/tum@0.02m": _run_record(row, "tum", segment_update_hz=1.0)
               for row in rows}
    assert runtime_sequence(["tum", "rtabmap"], all_tum, 0.02) == ("tum", False)
    assert runtime_sequence(["tum", "rtabmap"], runs, 0.02) == ("synthetic", True)


def test_segmentation_cache_computes_once(tmp_path):
    from evsmap.registry import READERS, SEGMENTERS
    from evsmap.runner.segcache import SegmentationCache

    seq = READERS.create("synthetic", frames=3, width=64, height=48)
    oracle = SEGMENTERS.create("oracle", seed=3)
    calls = []
    predict = oracle.predict

    def counting(frame):
        calls.append(frame.name)
        return predict(frame)

    oracle.predict = counting
    cache = SegmentationCache(tmp_path)
    first, ms, hit = cache.observations(oracle, seq, [0, 1, 2], key={"s": "oracle"})
    assert not hit and len(calls) == 3 and len(ms) == 3
    again, _, hit = cache.observations(oracle, seq, [0, 1, 2], key={"s": "oracle"})
    assert hit and len(calls) == 3
    for a, b in zip(first, again, strict=True):
        assert np.array_equal(a.classes, b.classes) and np.array_equal(a.probs, b.probs)
    # another key (another segmenter, other frames) is another entry
    cache.observations(oracle, seq, [0, 1], key={"s": "oracle"})
    assert len(calls) == 5
    from evsmap.measure.timing_policy import TimingPolicy

    policy = TimingPolicy(min_runs=3, max_runs=3, warmup=1, warmup_s=0.0)
    calls.clear()
    timing, hit = cache.timings(oracle, seq, [0, 1], key={"s": "oracle"}, policy=policy)
    # the frames in order, cycling, after a warm-up on the first; then stored
    assert not hit and len(timing["predict_ms"]) == 3 and timing["stopped"] == "max_runs"
    assert [c for c in calls] == [seq.frame(i).name for i in (0, 0, 1, 0)]
    assert cache.timings(oracle, seq, [0, 1], key={"s": "oracle"}, policy=policy) == (timing, True)


def test_mapping_run_on_the_synthetic_sequence(ctx):
    from evsmap.runner.execute import execute_mapping

    ctx.synthetic.update(frames=3, width=80, height=60)
    ctx.resolution = 0.1  # Table IV's: its map is kept for the report's views
    run = MappingRun("evsmap", "EVSMap", Component("oracle"), Component("multiclass-bayes"),
                     "synthetic", 0.1)
    # the oracle stands for a network here: its "timing" is the oracle's own
    rec = execute_mapping(run, ctx)
    assert rec.status == "ok", rec.error
    assert rec.values["frames"] == 3 and rec.values["map_bytes"] > 0
    assert 0.5 < rec.values["precision"] <= 1.0
    assert (Path(ctx.out) / "artifacts" / "map-evsmap-synthetic.npz").is_file()
    assert rec.environment["cpu"]
    # the front end's counts per frame, the size under each reading, the growth of a --quick
    # run at its end only (measure.growth.QUICK_GROWTH_POINTS; a full run's short sequence
    # takes half-way and the end)
    assert rec.cell_peak_rss_bytes > 0
    fe = rec.details["front_end"]
    assert fe["name"] == "generator" and len(fe["centroids"]) == 3
    # SSMI saves its colour-only ColorOcTree; its octomap_full message carries the semantics
    assert rec.values["map_bytes_colour"] == rec.values["map_bytes"]
    assert rec.values["map_bytes_message"] > rec.values["map_bytes"]
    growth = rec.details["growth"]
    assert [g["frames"] for g in growth] == [3]
    assert growth[-1]["nodes"] == rec.values["nodes"]
    assert growth[-1]["colour_bytes"] == rec.values["map_bytes_colour"]
    assert growth[-1]["message_bytes"] == rec.values["map_bytes_message"]


def test_accuracy_cell_with_a_dataset_and_weights(tmp_path, nyuv2_samples_dir):
    import shutil

    import torch

    from evsmap.registry import SEGMENTERS
    from evsmap.runner.execute import execute_spec

    # a prepared NYUv2 folder: the two real samples as the test split
    root = tmp_path / "data"
    shutil.copytree(nyuv2_samples_dir, root / "nyuv2")
    (root / "nyuv2" / "test.txt").write_text("000433\n000464\n")
    (root / "nyuv2" / "train.txt").write_text("")
    weights = tmp_path / "weights"
    weights.mkdir()
    torch.manual_seed(1)
    torch.save(SEGMENTERS.create("feagnet-v1").module.state_dict(),
               weights / "feagnet-v1@nyuv2.pt")
    ctx = RunContext.create(tmp_path / "run", data_root=root, weights_dir=weights, quick=True)
    plan = matrix.plan(ctx, ["table1"])
    spec = next(s for s in plan.specs if s.key == "table1/feagnet-v1/accuracy/nyuv2:test[miou]")
    assert spec.needs == ()
    rec = execute_spec(spec, ctx)
    assert rec.status == "ok", rec.error
    assert 0.0 <= rec.values[spec.metrics[0]] <= 1.0
    assert rec.details["pixels"] > 500_000  # both images' labelled pixels
    assert "nyuv2 test split, 2 images, weights feagnet-v1@nyuv2.pt" in rec.notes[0]
    # SUN RGB-D is still missing
    sun = next(s for s in plan.specs if s.key == "table1/feagnet-v1/accuracy/sunrgbd:test[miou]")
    assert "dataset:sunrgbd" in sun.needs


def test_a_missing_sample_names_the_fetch_command():
    assert needs_text(["dataset:tum"]) == (
        "n/a - needs the tum dataset (`evsmap datasets fetch tum-fr1-xyz`)")
    assert "fetch" not in needs_text(["dataset:nyuv2"])


def test_a_contended_mapping_run_flags_the_runtime_cell(ctx):
    from dataclasses import replace

    specs = {s.key: s for s in expand(load_tables()["table4"])}
    flag = "contended: the calibration matmul ran 3.00x slower"
    runs = {r.key: r for r in [
        replace(_run_record("evsmap", "synthetic", segment_update_hz=7.5, map_bytes=1e6),
                details={"timing_flag": flag}),
        _run_record("orgbmap", "synthetic", segment_update_hz=25.0, map_bytes=3e5),
    ]}
    rate = table4_record(specs["table4/evsmap/mapping/tum+rtabmap+asl+ours1+ours2@0.02m"
                               "[runtime_hz]"], runs, ctx)
    assert rate.details["timing_flag"] == flag
    orgb = table4_record(specs["table4/orgbmap/mapping/tum+rtabmap+asl+ours1+ours2@0.02m"
                               "[runtime_hz]"], runs, ctx)
    assert "timing_flag" not in orgb.details


def test_record_files_are_readable_by_others(tmp_path):
    import os
    import stat

    from evsmap.runner.records import RecordStore

    store = RecordStore(tmp_path / "records")
    path = store.write(_run_record("evsmap", "synthetic", segment_update_hz=1.0))
    mask = os.umask(0)
    os.umask(mask)
    assert stat.S_IMODE(path.stat().st_mode) == 0o666 & ~mask


def _contended(slowdown):
    rec = _run_record("evsmap", "synthetic", segment_update_hz=7.5 / slowdown, map_bytes=1e6)
    rec.details = {"contention": {"slowdown": slowdown, "contended": slowdown > 1.4}}
    return rec


@pytest.mark.parametrize("strict", [False, True])
def test_a_contended_mapping_run_is_run_again_and_the_calmer_try_kept(ctx, monkeypatch, strict):
    from dataclasses import replace

    tries = iter([_contended(2.0), _contended(1.1)])
    monkeypatch.setattr(matrix, "_mapping_worker", lambda run, data: next(tries).as_dict())
    monkeypatch.setattr(matrix.time, "sleep", lambda s: None)
    run = MappingRun(row="evsmap", label="EVSMap", sequence="synthetic", resolution=0.05,
                     updater=Component("multiclass-bayes"), segmenter=None)
    rec = matrix._timed_mapping(run, replace(ctx, strict_timing=strict), Inline)
    assert rec.status == "ok" and rec.details["contention"]["slowdown"] == 1.1
    assert "first try was contended: the calibration matmul ran 2.00x slower" in rec.notes[-1]


def test_strict_timing_refuses_a_mapping_run_contended_twice(ctx, monkeypatch):
    from dataclasses import replace

    tries = iter([_contended(2.0), _contended(3.0)])
    monkeypatch.setattr(matrix, "_mapping_worker", lambda run, data: next(tries).as_dict())
    monkeypatch.setattr(matrix.time, "sleep", lambda s: None)
    run = MappingRun(row="evsmap", label="EVSMap", sequence="synthetic", resolution=0.05,
                     updater=Component("multiclass-bayes"), segmenter=None)
    loose = matrix._timed_mapping(run, ctx, Inline)
    assert loose.status == "ok" and loose.details["contention"]["slowdown"] == 2.0
    tries = iter([_contended(2.0), _contended(3.0)])
    rec = matrix._timed_mapping(run, replace(ctx, strict_timing=True), Inline)
    assert rec.status == "na" and rec.needs == ["an idle machine"]
    assert "2.00x slower" in rec.reason


def test_a_calm_mapping_run_runs_once(ctx, monkeypatch):
    calls = []

    def worker(run, data):
        calls.append(run)
        return _contended(1.05).as_dict()

    monkeypatch.setattr(matrix, "_mapping_worker", worker)
    run = MappingRun(row="evsmap", label="EVSMap", sequence="synthetic", resolution=0.05,
                     updater=Component("multiclass-bayes"), segmenter=None)
    assert matrix._timed_mapping(run, ctx, Inline).status == "ok" and len(calls) == 1


def test_a_host_slowdown_with_idle_cores_is_flagged_not_timed_again(ctx, monkeypatch):
    from dataclasses import replace

    from evsmap.measure.contention import HOST_SLOWDOWN_NOTE, retry_can_help

    def host_slow():
        rec = _contended(1.9)
        rec.details["contention"]["other_share"] = 0.0
        return rec

    calls = []

    def worker(run, data):
        calls.append(run)
        return host_slow().as_dict()

    monkeypatch.setattr(matrix, "_mapping_worker", worker)
    monkeypatch.setattr(matrix.time, "sleep", lambda s: None)
    run = MappingRun(row="evsmap", label="EVSMap", sequence="synthetic", resolution=0.05,
                     updater=Component("multiclass-bayes"), segmenter=None)
    rec = matrix._timed_mapping(run, ctx, Inline)
    assert len(calls) == 1 and rec.notes[-1] == HOST_SLOWDOWN_NOTE
    # other work on the cores may pass: that one is timed again; --strict-timing always is
    assert retry_can_help({"other_share": 0.5}) and retry_can_help({"other_share": None})
    calls.clear()
    matrix._timed_mapping(run, replace(ctx, strict_timing=True), Inline)
    assert len(calls) == 2
