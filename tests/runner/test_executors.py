"""The scheduler's side of the executors, without Ray: timed cells one at a time per timing
slot and all of them run, which nodes of a mixed cluster time, and the local executor as the
default."""

from __future__ import annotations

import threading
import time

import pytest
from runner_fixtures import Inline

import evsmap.runner.matrix as matrix
from evsmap.runner.executors import LocalExecutor, TimingSlot
from evsmap.runner.ray_executor import timing_nodes
from evsmap.runner.records import CellRecord


def _record(key: str) -> CellRecord:
    return CellRecord(key=key, table="extra", row=key, label=key, kind="mapping", metrics=[],
                      status="ok")


@pytest.mark.parametrize("n_slots", [1, 3])
def test_timed_cells_run_one_at_a_time_per_slot(n_slots):
    slots = [TimingSlot(name=f"node{i}", cpus=4, node_id=str(i)) for i in range(n_slots)]
    lock = threading.Lock()
    busy: dict[str, int] = {}
    most: dict[str, int] = {}
    ran: list[tuple[str, str]] = []
    kept: list[str] = []

    def run_one(item: str, slot: TimingSlot) -> CellRecord:
        with lock:
            busy[slot.name] = busy.get(slot.name, 0) + 1
            most[slot.name] = max(most.get(slot.name, 0), busy[slot.name])
            ran.append((item, slot.name))
        time.sleep(0.01)
        with lock:
            busy[slot.name] -= 1
        return _record(item)

    items = [f"cell{i}" for i in range(9)]
    matrix._run_timed(items, run_one, slots, lambda rec: kept.append(rec.key))
    assert sorted(kept) == items and sorted(i for i, _ in ran) == items
    assert set(most.values()) == {1}  # never two timed cells on one slot
    if n_slots == 1:
        assert kept == items  # one slot: in order, in this thread
    matrix._run_timed([], run_one, [], kept.append)  # nothing to time needs no slot


def _node(host, cpu, cpus, head=False):
    return {"host": host, "cpu": cpu, "cpus": cpus, "head": head}


def test_timing_nodes_are_alike():
    epyc = [_node("head", "EPYC", 16, head=True), _node("w1", "EPYC", 16),
            _node("w2", "EPYC", 8), _node("w3", "Xeon", 16), _node("w4", "Xeon", 16)]
    # the head's kind times, though another kind has as many nodes
    assert [n["host"] for n in timing_nodes(epyc)] == ["head", "w1"]
    # a head without CPUs is not listed: the largest group of alike nodes times
    assert [n["host"] for n in timing_nodes(epyc[1:])] == ["w3", "w4"]
    # ties: the most CPUs
    assert [n["host"] for n in timing_nodes([_node("a", "X", 4), _node("b", "Y", 8)])] == ["b"]


def test_timing_nodes_share_the_instruction_set():
    # the same model name on hosts that expose different vector sets (a hypervisor that hides
    # AVX-512) is two kinds: the head's times alone
    nodes = [{**_node("head", "EPYC", 16, head=True), "instruction_set": "avx512-vnni"},
             {**_node("w1", "EPYC", 16), "instruction_set": "avx2"},
             {**_node("w2", "EPYC", 16), "instruction_set": "avx512-vnni"}]
    assert [n["host"] for n in timing_nodes(nodes)] == ["head", "w2"]


def test_local_is_the_default_and_keeps_its_pools(tmp_path):
    from evsmap.runner.context import RunContext

    ex = matrix.make_executor("local")
    assert isinstance(ex, LocalExecutor) and ex.describe() == {"name": "local"}
    assert ex.timing_slots() == [TimingSlot(name="this machine")]
    ctx = RunContext.create(tmp_path / "run", data_root=tmp_path, quick=True)
    plan = matrix.Plan([], [], [])
    with pytest.raises(ValueError, match="not both"):
        matrix.run_matrix(ctx, plan, pool=lambda n: Inline(), executor=ex)
    assert matrix.run_matrix(ctx, plan, executor=ex) == []


def _mark_and_report(value):
    """Set a module-level mark in the worker and report what the worker saw before."""
    import os
    import sys

    import evsmap.runner.executors as executors

    seen = getattr(executors, "_test_mark", None)
    executors._test_mark = value
    return {"pid": os.getpid(), "seen": seen, "torch": "torch" in sys.modules}


def test_each_timed_cell_gets_a_process_no_cell_ran_in():
    from evsmap.runner.executors import fresh_process

    reports = []
    for value in ("first", "second"):
        with fresh_process() as ex:
            reports.append(ex.submit(_mark_and_report, value).result(timeout=120))
    assert reports[0]["pid"] != reports[1]["pid"]
    assert reports[0]["seen"] is None and reports[1]["seen"] is None  # nothing inherited
    assert all(r["torch"] for r in reports)  # the heavy imports came with the process
