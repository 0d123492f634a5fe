"""The backend of a speed measurement is an object (evsmap.measure.speed_backends) and its timing
rule is always a policy: a backend written outside evsmap is timed like the built-in ones, the
names the command line and the sweeps use build the right class, and the records keep their
keys."""

from __future__ import annotations

import dataclasses
from typing import ClassVar

import pytest
import torch
from torch import nn

from evsmap.errors import InvalidDataError, UnknownNameError
from evsmap.measure.speed import SpeedRecord, measure_speed
from evsmap.measure.speed_backends import (
    BACKENDS,
    OnnxRuntime,
    PreparedPass,
    TorchCompiled,
    TorchCudaGraph,
    TorchEager,
    make_backend,
)
from evsmap.measure.timing_policy import RoundsPolicy

RECORD_KEYS = [
    "backend", "height", "width", "runs", "warmup", "threads", "ms_median", "ms_iqr",
    "fps_median", "fps_iqr", "times_ms", "macs", "roofline_gmacs", "achieved_gmacs",
    "roofline_fraction", "versions", "cpu", "instruction_set", "rounds", "rel_iqr", "stable",
    "contention", "calibration_gmacs", "ci_ms", "rel_ci", "stopped", "timed_s", "policy",
    "session_s", "device", "timer", "autocast", "provider", "compile_s", "settle", "gpu",
    "compile_mode", "channels_last", "timing", "wall_ms_median", "dispatch_ms", "busy"]
"""A speed record's keys, in order, as ``evsmap speed --json`` wrote them before the backends
were objects."""


class Counting(nn.Module):
    def __init__(self) -> None:
        super().__init__()
        self.conv = nn.Conv2d(1, 2, 1)
        self.calls = 0

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        self.calls += 1
        return self.conv(x)


@dataclasses.dataclass(frozen=True)
class Twice(TorchEager):
    """A backend defined outside evsmap: each timed pass runs the module twice."""

    name: ClassVar[str] = "twice"

    def _build(self, module, inputs, device, timer) -> PreparedPass:
        model, args, context = self._placed(module, inputs, device)

        def call():
            model(*args)
            return model(*args)

        return PreparedPass(call, context)


def test_a_new_backend_is_a_class_timed_like_the_others():
    net = Counting()
    rec = measure_speed(net, torch.zeros(1, 1, 4, 4), backend=Twice(),
                        policy=RoundsPolicy(runs=3, warmup=1), threads=1, macs=1, roofline=1.0)
    assert rec.backend == "twice" and rec.runs == 3 and rec.warmup == 1
    assert net.calls == 2 * (3 + 1)  # every warm-up and timed pass ran the backend's call
    assert list(rec.as_dict()) == RECORD_KEYS


def test_the_default_is_eager_fp32_in_one_round_of_twenty():
    rec = measure_speed(nn.Conv2d(1, 1, 1), torch.zeros(1, 1, 4, 4), threads=1, macs=1,
                        roofline=1.0)
    assert isinstance(rec, SpeedRecord)
    assert (rec.backend, rec.runs, rec.warmup, rec.rounds) == ("torch", 20, 3, 1)
    assert (rec.autocast, rec.provider, rec.compile_mode, rec.channels_last) == (
        None, None, None, False)
    assert rec.policy is None and rec.stable is None  # the record of a fixed count, as before


def test_names_build_their_classes_with_their_options():
    assert make_backend() == TorchEager()
    assert make_backend("torch", autocast="bf16", channels_last=True) == TorchEager(
        autocast="bf16", channels_last=True)
    assert make_backend("torch-compile", compile_mode="max-autotune") == TorchCompiled(
        mode="max-autotune")
    assert make_backend("torch-compile") == TorchCompiled(mode="default")
    assert make_backend("torch-cuda-graph", autocast="fp16") == TorchCudaGraph(autocast="fp16")
    ort = make_backend("onnxruntime", provider="tensorrt", autocast="fp16",
                       onnx={"key": "net", "input_names": ("rgb",)})
    assert ort == OnnxRuntime(provider="tensorrt", autocast="fp16", key="net",
                              input_names=("rgb",))
    # the torch backends run the module itself: the export's fields are not theirs
    assert make_backend("torch", onnx={"key": "net"}) == TorchEager()
    assert {make_backend(name).name for name in BACKENDS} == set(BACKENDS)


@pytest.mark.parametrize("build, error, words", [
    (lambda: TorchEager(autocast="fp8"), UnknownNameError, "unknown autocast"),
    (lambda: TorchCompiled(mode="fastest"), UnknownNameError, "unknown compile mode"),
    (lambda: OnnxRuntime(provider="npu"), UnknownNameError, "unknown ONNX Runtime provider"),
    (lambda: make_backend("tensorrt"), UnknownNameError, "known: onnxruntime, torch"),
    (lambda: make_backend("torch", provider="cpu"), InvalidDataError,
     "needs backend onnxruntime"),
])
def test_a_backend_refuses_what_is_not_its_own_when_made(build, error, words):
    with pytest.raises(error, match=words) as info:
        build()
    assert "\n" not in str(info.value)


def test_what_depends_on_the_device_is_refused_when_prepared():
    with pytest.raises(InvalidDataError, match="does not run on device cpu"):
        OnnxRuntime(provider="cuda").prepare(nn.Conv2d(1, 1, 1), [torch.zeros(1, 1, 2, 2)])
    with pytest.raises(InvalidDataError, match="only TensorRT"):
        OnnxRuntime(autocast="fp16").check(torch.device("cpu"))
