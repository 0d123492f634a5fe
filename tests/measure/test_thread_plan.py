"""The pipelined loop's thread plan (evsmap.measure.thread_plan): a pure function of the cores and
the device; 2 cores on the CPU is the plan the 2-core machines were measured with; and how near a
loop came to its slowest stage's rate (evsmap.measure.pipelined.loop_balance)."""

from __future__ import annotations

import os

import pytest

from evsmap.errors import InvalidDataError, UnknownNameError
from evsmap.measure.pipelined import (
    PIPELINED,
    SEQUENTIAL,
    StageThreads,
    loop_balance,
    stage_threads_option,
)
from evsmap.measure.thread_plan import STAGES, available_cores, thread_plan


@pytest.mark.parametrize("cores", [1, 2])
def test_one_and_two_cores_on_the_cpu_are_todays_pipelined_threads(cores):
    assert thread_plan(cores, "cpu").threads == PIPELINED


@pytest.mark.parametrize("cores, torch, update", [(1, 1, 1), (2, 1, 1), (4, 2, 1), (16, 10, 5)])
def test_the_cpu_plan_keeps_the_networks_sequential_threads(cores, torch, update):
    plan = thread_plan(cores, "cpu")
    assert plan.threads == StageThreads(segment=None, spinning=False, torch=torch,
                                        update=update, blas=1)
    if cores > 2:  # the reader, the update and the pre/post-processing fill the cores
        assert 1 + plan.threads.update + plan.threads.torch == cores


@pytest.mark.parametrize("device", ["cuda", "cuda:1"])
@pytest.mark.parametrize("cores, update", [(1, 1), (2, 1), (4, 2), (16, 14)])
def test_a_gpu_plan_gives_the_update_every_core_but_the_readers_and_the_launchers(
        device, cores, update):
    plan = thread_plan(cores, device)
    assert plan.threads == StageThreads(segment=1, spinning=False, torch=1, update=update,
                                        blas=1)
    assert plan.device == ("cuda:0" if device == "cuda" else "cuda:1")
    assert plan.device in plan.reasons["segment"]


@pytest.mark.parametrize("device", ["cpu", "cuda:0"])
@pytest.mark.parametrize("cores", [1, 2, 4, 16])
def test_every_stage_has_its_reason_in_the_record(device, cores):
    record = thread_plan(cores, device).as_dict()
    assert (record["cores"], record["device"], record["loop"]) == (cores, device, "pipelined")
    assert list(record["stages"]) == [k for k in STAGES if k != "spinning"]
    assert all(stage["reason"] for stage in record["stages"].values())
    assert record["stages"]["read"]["threads"] == 1
    assert record["spinning"]["enabled"] is False and record["spinning"]["reason"]


def test_the_sequential_loop_keeps_every_librarys_default():
    plan = thread_plan(16, "cuda", pipelined=False)
    assert plan.threads == SEQUENTIAL and plan.as_dict()["loop"] == "sequential"


def test_stage_threads_override_single_stages_of_the_plan():
    plan = thread_plan(16, "cpu").overridden({"update": 3})
    assert plan.threads == StageThreads(segment=None, spinning=False, torch=10, update=3, blas=1)
    assert plan.reasons["update"] == "--stage-threads update=3 (the plan: 5)"
    assert stage_threads_option([("torch", "4")], pipeline=True,
                                base=thread_plan(16, "cpu").threads).torch == 4


@pytest.mark.parametrize("cores", [0, -2, 1025, True, 2.0, "4"])
def test_a_bad_core_count_is_one_clear_error(cores):
    with pytest.raises(InvalidDataError, match=r"^--cores .*: plan for 1 to 1024 cores"):
        thread_plan(cores, "cpu")


def test_a_misspelt_device_is_refused():
    with pytest.raises(UnknownNameError, match="unknown device"):
        thread_plan(4, "gpu")


def test_the_default_cores_are_the_processs_cpus():
    assert available_cores() == len(os.sched_getaffinity(0))


def test_the_pipelined_loop_is_bounded_by_its_slowest_thread():
    stages = {"read": 20.0, "preprocess": 5.0, "network": 17.0, "postprocess": 6.0,
              "update": 25.0}
    balance = loop_balance(stages, 25.0, pipelined=True)  # 40 ms a frame
    assert balance["threads_ms"] == {"read": 20.0, "segment": 28.0, "update": 25.0}
    assert (balance["bound"], balance["bound_ms"]) == ("segment", 28.0)
    assert balance["reached"] == pytest.approx(0.7)  # 25 Hz of 1000 / 28
    assert balance["shares"] == pytest.approx({"read": 0.5, "preprocess": 0.125,
                                               "network": 0.425, "postprocess": 0.15,
                                               "update": 0.625})


def test_the_sequential_loop_is_bounded_by_all_its_stages():
    balance = loop_balance({"read": 10.0, "oracle": 30.0, "update": 40.0}, 10.0,
                           pipelined=False)
    assert (balance["bound"], balance["bound_ms"]) == ("all stages", 80.0)
    assert balance["reached"] == pytest.approx(0.8)
    assert sum(balance["shares"].values()) == pytest.approx(0.8)


def test_a_loop_without_a_segmenter_has_no_segment_thread():
    balance = loop_balance({"read": 10.0, "update": 40.0}, 20.0, pipelined=True)
    assert balance["threads_ms"] == {"read": 10.0, "update": 40.0}
    assert balance["bound"] == "update"


@pytest.mark.parametrize("stages, wall_hz", [({}, 10.0), ({"update": 1.0}, float("nan")),
                                             ({"update": 1.0}, 0.0)])
def test_no_balance_without_frames(stages, wall_hz):
    assert loop_balance(stages, wall_hz, pipelined=True) == {}
