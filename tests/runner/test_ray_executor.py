"""``reproduce --executor ray``: a local Ray cluster (2 CPUs) runs the same small matrix as the
local process pool and gets the same records (timings aside), each saying where it ran; a
resumed run keeps the finished records; the node checks, and the errors of an unknown executor,
an ``--address`` without Ray and a missing Ray."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import pytest

import evsmap.runner.matrix as matrix
from evsmap.cli.main import main
from evsmap.errors import EvsmapError
from evsmap.runner.context import RunContext
from evsmap.runner.mapping_plan import MappingRun
from evsmap.runner.records import RecordStore
from evsmap.tables.schema import Component

ray = pytest.importorskip("ray")

CELLS = ("table1/feagnet-v1/accuracy/nyuv2",  # n/a here: no dataset, no weights
         "table1/feagnet-v2/complexity",  # one configuration in two rows: measured once
         "table1/feagnet-v2-jetson/complexity")
TIMING = ("hz", "fps", "rss")
"""Values that are timings or depend on the process (left out of the comparison)."""


@pytest.fixture(scope="module")
def cluster():
    """One local Ray cluster of 2 CPUs for the module; the executor under test finds it
    initialised and leaves it running."""
    started = not ray.is_initialized()
    if started:
        ray.init(num_cpus=2, include_dashboard=False, logging_level="WARNING")
    yield ray
    if started:
        ray.shutdown()


def _context(root: Path, name: str) -> RunContext:
    data = root / "data"
    data.mkdir(exist_ok=True)
    ctx = RunContext.create(root / name, data_root=data, quick=True)
    Path(ctx.out).mkdir()
    ctx.synthetic.update(frames=3, width=80, height=60)
    ctx.frames = 3
    return ctx


def _plan(ctx: RunContext) -> matrix.Plan:
    """A na cell, two complexity cells of one configuration, and a timed mapping run (the
    oracle's labels into EVSMap's updater on a 3-frame synthetic room)."""
    full = matrix.plan(ctx, ["table1"])
    specs = [s for s in full.specs if s.key.startswith(CELLS)]
    assert len(specs) == 3
    run = MappingRun("evsmap", "EVSMap", Component("oracle"), Component("multiclass-bayes"),
                     "synthetic", 0.1)
    return matrix.Plan(specs, [run], ["synthetic"])


def _json(record) -> str:
    """A record as its file holds it (NaN compares equal to NaN here)."""
    return json.dumps(record.as_dict(), sort_keys=True)


def _same_but_timing(a: dict, b: dict) -> None:
    keys = {k for k in a | b if not any(t in k for t in TIMING)}
    assert {k: a.get(k) for k in keys} == pytest.approx({k: b.get(k) for k in keys}), keys


@pytest.mark.slow
def test_ray_runs_the_matrix_as_the_local_pool_does(cluster, tmp_path):
    local_ctx, ray_ctx = _context(tmp_path, "local"), _context(tmp_path, "ray")
    local = {r.key: r for r in matrix.run_matrix(local_ctx, _plan(local_ctx), workers=1)}
    with matrix.make_executor("ray") as executor:
        executor.prepare(ray_ctx)
        (slot,) = executor.timing_slots()  # one node: one timed cell at a time
        assert slot.cpus == 2 and slot.node_id == ray.get_runtime_context().get_node_id()
        assert [n["times"] for n in executor.describe()["nodes"]] == [True]
        got = {r.key: r for r in matrix.run_matrix(ray_ctx, _plan(ray_ctx), workers=1,
                                                   executor=executor)}
    assert ray.is_initialized()  # a cluster it did not start is left running
    assert list(got) == list(local) and len(got) == 4
    for key, rec in got.items():
        twin = local[key]
        assert (rec.status, rec.inputs, rec.needs, rec.reason) == \
               (twin.status, twin.inputs, twin.needs, twin.reason), key
        _same_but_timing(rec.values, twin.values)
    v2 = got["table1/feagnet-v2/complexity@640x480[params,flops]"]
    assert v2.status == "ok" and v2.values["params"] > 1e6 and v2.values["flops"] > 1e9
    mapped = got["extra/mapping/evsmap/synthetic@0.1m"]
    assert mapped.status == "ok", mapped.error
    assert mapped.values["frames"] == 3 and mapped.values["map_bytes"] > 0
    assert math.isfinite(mapped.values["segment_update_hz"])
    # where each cell ran: pooled cells reserve their threads, the timed one the whole node
    node = ray.get_runtime_context().get_node_id()
    threads = min(ray_ctx.threads, 2)  # the run's threads, at most the node's CPUs
    assert v2.environment["executor"] == {"name": "ray", "node_id": node, "cpus": threads,
                                          "whole_node": False}
    assert v2.environment["host"] == slot.name
    assert v2.environment["threads"] == threads
    assert mapped.environment["executor"]["whole_node"] is True
    assert mapped.environment["executor"]["cpus"] == mapped.environment["threads"] == 2
    assert local["extra/mapping/evsmap/synthetic@0.1m"].environment["executor"] == {
        "name": "local"}
    assert "executor" not in got["table1/feagnet-v1/accuracy/nyuv2:test[miou]"].environment
    # the driver wrote every record
    stored = {r.key: _json(r) for r in RecordStore(ray_ctx.out)}
    assert stored == {k: _json(r) for k, r in got.items()}

    # resume with Ray: the ok records are kept as they are, nothing is measured again
    with matrix.make_executor("ray") as executor:
        again = matrix.run_matrix(ray_ctx, _plan(ray_ctx), resume=True, executor=executor)
    for rec in again:
        if rec.status == "ok":
            assert _json(rec) == _json(got[rec.key])
    assert [r.key for r in again] == list(got)


def test_the_node_probe_names_what_a_node_cannot_see(tmp_path):
    from evsmap.runner.ray_executor import _probe
    from evsmap.version import evsmap_version

    probe = _probe([str(tmp_path), str(tmp_path / "elsewhere")])
    assert probe["missing"] == [str(tmp_path / "elsewhere")]
    assert probe["evsmap"] == evsmap_version() and probe["cpu"]
    assert probe["instruction_set"]


def test_unknown_executor_and_address_without_ray():
    with pytest.raises(EvsmapError, match="unknown executor 'dask'"):
        matrix.make_executor("dask")
    with pytest.raises(EvsmapError, match="--address only applies with --executor ray"):
        matrix.make_executor("local", address="head:6379")


def test_an_address_where_nothing_answers_fails_at_once(tmp_path, capsys):
    import socket

    with socket.socket() as sock:  # a port that was free a moment ago
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    code = main(["reproduce", "--executor", "ray", "--address", f"127.0.0.1:{port}",
                 "--quick", "--out", str(tmp_path / "run")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1
    assert f"nothing answers at 127.0.0.1:{port}" in err[0]
    assert not (tmp_path / "run").exists()


def test_missing_ray_is_one_line_and_exit_2(monkeypatch, tmp_path, capsys):
    monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` now fails
    with pytest.raises(EvsmapError, match=r'pip install "evsmap\[ray\]"'):
        matrix.make_executor("ray")
    code = main(["reproduce", "--executor", "ray", "--quick", "--out", str(tmp_path / "run")])
    err = capsys.readouterr().err
    assert code == 2
    assert err.strip().splitlines() == [
        'evsmap reproduce: error: --executor ray needs Ray, which is not installed: install '
        'it with pip install "evsmap[ray]"']
    assert not (tmp_path / "run").exists()  # refused before anything was written
    with pytest.raises(SystemExit) as exc:
        main(["reproduce", "--executor", "dask"])
    assert exc.value.code == 2
    assert "invalid choice: 'dask'" in capsys.readouterr().err
