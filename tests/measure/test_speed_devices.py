"""``measure_speed`` beyond eager fp32 on the CPU: torch.compile, autocast, ONNX Runtime's
providers, the device, and the refusals of settings that do not go together; the per-pass
timer under a timing policy; the faithful post-processing as it runs on a GPU (on the CPU here:
the function is the device's)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torch import nn

from evsmap.devices import DeviceUnavailableError
from evsmap.errors import InvalidDataError, UnknownNameError
from evsmap.measure import measure_speed
from evsmap.measure.speed_backends import make_backend
from evsmap.measure.timing_policy import RoundsPolicy, TimingPolicy, time_until_precise
from evsmap.models.ort_providers import check_used, provider_chain


class DtypeProbe(nn.Module):
    """A conv whose forward notes the dtype its convolution computed in."""

    def __init__(self) -> None:
        super().__init__()
        self.conv = nn.Conv2d(3, 4, 3, padding=1)
        self.seen: list[torch.dtype] = []

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = self.conv(x)
        self.seen.append(y.dtype)
        return y


def _speed(module, *, backend="torch", autocast=None, provider=None, device="cpu", **onnx):
    """Three passes of ``module`` on the backend these settings name (``make_backend``)."""
    return measure_speed(module, torch.rand(1, 3, 16, 16),
                         backend=make_backend(backend, autocast=autocast, provider=provider,
                                              onnx=onnx),
                         policy=RoundsPolicy(runs=3, warmup=1), threads=1, roofline=1.0,
                         macs=1, device=device)


@pytest.mark.parametrize("autocast, dtype", [(None, torch.float32), ("bf16", torch.bfloat16)])
def test_autocast_runs_the_passes_at_its_dtype(autocast, dtype):
    net = DtypeProbe()
    rec = _speed(net, autocast=autocast)
    assert set(net.seen) == {dtype} and rec.autocast == autocast
    assert (rec.device, rec.timer, rec.gpu, rec.settle) == ("cpu", "host clock", {}, None)


def test_torch_compile_is_a_backend_whose_compilation_is_timed_apart(tmp_path, monkeypatch):
    monkeypatch.setenv("TORCHINDUCTOR_CACHE_DIR", str(tmp_path / "inductor"))
    net = nn.Sequential(nn.Conv2d(3, 4, 3, padding=1), nn.ReLU())
    rec = _speed(net, backend="torch-compile")
    assert rec.backend == "torch-compile" and rec.compile_s is not None
    assert rec.compile_s > max(rec.times_ms) / 1e3  # the first call compiled
    assert rec.runs == 3 and rec.fps_median > 0


def test_onnxruntime_names_the_provider_it_ran_on(tmp_path):
    rec = _speed(nn.Conv2d(3, 4, 3), backend="onnxruntime", cache_dir=tmp_path, key="c")
    assert rec.provider == "CPUExecutionProvider"


@pytest.mark.parametrize("kw, error, words", [
    ({"backend": "torch", "provider": "cpu"}, InvalidDataError, "needs backend onnxruntime"),
    ({"backend": "onnxruntime", "provider": "cuda"}, InvalidDataError, "does not run on"),
    ({"backend": "onnxruntime", "provider": "npu"}, UnknownNameError, "unknown ONNX Runtime"),
    ({"backend": "onnxruntime", "autocast": "fp16"}, InvalidDataError, "only TensorRT"),
    ({"autocast": "fp8"}, UnknownNameError, "unknown autocast"),
    ({"device": "gpu"}, UnknownNameError, "unknown device"),
])
def test_settings_that_do_not_go_together_are_refused(kw, error, words, tmp_path):
    with pytest.raises(error, match=words):
        _speed(nn.Conv2d(3, 4, 3), cache_dir=tmp_path, **kw)


@pytest.mark.skipif(torch.cuda.is_available(), reason="this machine has a GPU")
def test_a_gpu_asked_for_where_there_is_none_is_refused():
    with pytest.raises(DeviceUnavailableError, match="--device cuda"):
        _speed(nn.Conv2d(3, 4, 3), device="cuda")


def test_a_provider_this_onnxruntime_lacks_names_the_extra():
    import onnxruntime as ort

    if "CUDAExecutionProvider" in ort.get_available_providers():
        pytest.skip("this ONNX Runtime has the CUDA provider")
    with pytest.raises(DeviceUnavailableError, match=r"evsmap\[gpu\]"):
        provider_chain("cuda")
    assert provider_chain("cpu") == ["CPUExecutionProvider"]


def test_a_silent_fall_back_to_the_cpu_is_caught():
    class Session:
        def get_providers(self):
            return ["CPUExecutionProvider"]

    assert check_used(Session(), "cpu") == "CPUExecutionProvider"
    with pytest.raises(DeviceUnavailableError, match="fell back to CPUExecutionProvider"):
        check_used(Session(), "tensorrt")


def test_a_pass_timer_replaces_the_clock_for_the_passes_only():
    policy = TimingPolicy(warmup=1, warmup_s=0.0, min_runs=4, max_runs=4, budget_s=10.0)
    calls = []
    passes = time_until_precise(lambda: calls.append(1), policy,
                                pass_timer=lambda call: (call(), 0.25)[1])
    assert passes.times_s == [0.25] * 4 and len(calls) == 5  # 1 warm-up + 4 timed


def test_the_device_post_processing_matches_the_cpu_reference():
    from evsmap.segmenters.network import _top_k_on_device
    from evsmap.segmenters.topk import top_k_softmax

    logits = torch.randn(1, 7, 12, 16, generator=torch.Generator().manual_seed(3))
    obs = _top_k_on_device(logits, (24, 32), 3, 7)
    up = nn.functional.interpolate(logits, size=(24, 32), mode="bilinear", align_corners=False)
    classes, probs = top_k_softmax(up[0], 3)
    np.testing.assert_array_equal(obs.classes, classes)
    np.testing.assert_allclose(obs.probs, probs, atol=1e-6)
    assert obs.classes.dtype == np.int16 and obs.probs.dtype == np.float32
