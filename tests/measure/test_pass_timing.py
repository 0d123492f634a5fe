"""The one definition of how a pass is timed (evsmap.measure.pass_timing) and what speed's records
carry of it: threads, pinning, clocks, dispatch, where the time goes, the GPU-only backends
refused on the CPU in one line."""

import os
from types import SimpleNamespace

import pytest
import torch
from torch import nn

from evsmap.devices import DeviceUnavailableError, PassTimer
from evsmap.errors import InvalidDataError, UnknownNameError
from evsmap.measure import measure_speed
from evsmap.measure.pass_timing import (
    HOST,
    LAUNCH_BOUND_SHARE,
    bound_of,
    busy_seconds,
    device_busy,
    kernel_intervals,
    pass_timing,
)
from evsmap.measure.speed_backends import TorchEager, make_backend
from evsmap.measure.timing_policy import RoundsPolicy

needs_affinity = pytest.mark.skipif(not hasattr(os, "sched_getaffinity"), reason="no affinity")


def net() -> nn.Module:
    return nn.Sequential(nn.Conv2d(3, 8, 3, padding=1), nn.ReLU(), nn.Conv2d(8, 4, 1)).eval()


def x() -> torch.Tensor:
    return torch.rand(1, 3, 16, 20, generator=torch.Generator().manual_seed(0))


def test_union_of_kernel_intervals_counts_overlaps_once():
    # two streams overlap on [5, 8); a kernel inside another adds nothing; a gap is not busy
    assert busy_seconds([(0, 8), (5, 10), (6, 7), (20, 25)]) == pytest.approx(15e-6)
    assert busy_seconds([]) == 0.0


def test_bound_threshold():
    assert bound_of(LAUNCH_BOUND_SHARE - 0.01) == "launch"
    assert bound_of(LAUNCH_BOUND_SHARE) == "device"
    assert bound_of(None) is None


def test_kernel_intervals_keep_only_gpu_kernels():
    from torch.autograd import DeviceType

    def event(kind, start, end):
        return SimpleNamespace(device_type=kind, time_range=SimpleNamespace(start=start, end=end))

    events = [event(DeviceType.CPU, 0, 100), event(DeviceType.CUDA, 10, 30),
              event(DeviceType.CUDA, 40, 40), event(DeviceType.CUDA, 50, 60)]
    assert kernel_intervals(events) == [(10.0, 30.0), (50.0, 60.0)]


def test_cpu_pass_is_host_bound_and_needs_no_profiler():
    assert device_busy(lambda: None, 0.01, "cpu") == HOST
    assert HOST.bound == "host"


def test_definition_defaults():
    cpu = pass_timing("cpu", 1)
    assert (cpu.clock, cpu.settle, cpu.cudnn_benchmark) == ("host clock", False, False)
    assert pass_timing("cpu").host_threads == torch.get_num_threads()
    assert pass_timing("cpu", 2, pin=False).cpus is None
    with pytest.raises(UnknownNameError):
        pass_timing("gpu")
    with pytest.raises(ValueError, match="threads"):
        pass_timing("cpu", 0)


@needs_affinity
def test_pinning_is_the_gates_rule_and_is_undone():
    allowed = os.sched_getaffinity(0)
    timing = pass_timing("cpu", 1)
    assert timing.cpus == (min(allowed),)  # the lowest CPU, like the gate's --cpu default
    before = torch.get_num_threads()
    with timing.applied():
        assert os.sched_getaffinity(0) == {min(allowed)}
        assert torch.get_num_threads() == 1
    assert os.sched_getaffinity(0) == allowed and torch.get_num_threads() == before
    with pytest.raises(ValueError, match="not ones this process may use"):
        pass_timing("cpu", 1, cpus=[max(allowed) + 1000])


def test_timer_keeps_wall_and_dispatch_and_resets():
    timer = PassTimer("cpu")
    seconds = timer(lambda: sum(range(1000)))
    assert timer.walls == [seconds] and timer.dispatches == [seconds]
    timer.reset()
    assert timer.walls == [] and timer.dispatches == []


def test_speed_record_states_its_timing_and_where_the_time_goes():
    rec = measure_speed(net(), x(), policy=RoundsPolicy(runs=5, warmup=1), threads=1,
                        roofline_size=32)
    assert rec.timing["host_threads"] == 1 and rec.timing["clock"] == "host clock"
    if hasattr(os, "sched_getaffinity"):
        assert rec.timing["cpus"] == [min(os.sched_getaffinity(0))]
    # on the CPU the dispatch is the pass, and the wall clock is the timed clock
    assert rec.wall_ms_median == pytest.approx(rec.ms_median)
    assert rec.dispatch_ms == pytest.approx(rec.ms_median)
    assert rec.bound == "host" and rec.busy["busy_share"] is None
    assert rec.as_dict()["timing"]["device"] == "cpu"


def test_channels_last_runs_and_gives_the_same_labels():
    module, inputs = net(), x()
    eager = TorchEager().prepare(module, [inputs])
    last = TorchEager(channels_last=True).prepare(module, [inputs])
    with eager.context():
        a = eager.call()
    with last.context():
        b = last.call()
    assert torch.equal(a.argmax(1), b.argmax(1))
    assert next(module.parameters()).is_contiguous()  # the caller's module is left as it was
    rec = measure_speed(module, inputs, backend=TorchEager(channels_last=True),
                        policy=RoundsPolicy(runs=3, warmup=0), roofline_size=32)
    assert rec.channels_last and rec.compile_mode is None


def test_gpu_only_and_mismatched_settings_refused_in_one_line():
    with pytest.raises(DeviceUnavailableError, match="needs a GPU") as info:
        make_backend("torch-cuda-graph").prepare(net(), [x()])
    assert "\n" not in str(info.value)
    with pytest.raises(UnknownNameError, match="compile mode"):
        make_backend("torch-compile", compile_mode="fastest")
    with pytest.raises(InvalidDataError, match="needs backend torch-compile"):
        make_backend("torch", compile_mode="reduce-overhead")
    with pytest.raises(InvalidDataError, match="channels-last"):
        make_backend("onnxruntime", channels_last=True)


def test_speed_cells_say_where_a_gpu_pass_went():
    from evsmap.runner.network_cells import busy_text

    assert busy_text({"kernel_ms": 2.5, "busy_share": 0.21, "bound": "launch"}) == (
        "GPU busy 21 % of the pass (2.50 ms of kernels): launch-bound")
    assert "not measured: the profiler recorded no GPU kernel" in busy_text(
        {"busy_share": None, "why": "the profiler recorded no GPU kernel"})


@pytest.mark.skipif(torch.cuda.is_available(), reason="a machine with a GPU")
def test_a_gpu_asked_of_a_machine_without_one_is_one_line():
    with pytest.raises(DeviceUnavailableError) as info:
        measure_speed(net(), x(), device="cuda:7", roofline_size=32)
    assert "\n" not in str(info.value) and "--device cuda:7" in str(info.value)
