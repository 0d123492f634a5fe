"""The backend sweep on the CPU: GPU-only variants refused in one line each, the labels of every
timed variant compared with eager fp32's, reduced precision held to its tolerance, and the
fastest qualifying variant picked by its rule."""

from __future__ import annotations

import pytest
import torch
from torch import nn

from evsmap.devices import DeviceUnavailableError
from evsmap.errors import UnknownNameError
from evsmap.measure.backend_sweep import (
    REDUCED_PRECISION_AGREEMENT,
    REFERENCE,
    VariantResult,
    argmax_labels,
    backend_sweep,
    fastest_qualifying,
    label_agreement,
    select_variants,
    variants,
)
from evsmap.measure.speed import measure_speed
from evsmap.measure.timing_policy import TimingPolicy

POLICY = TimingPolicy(target_rel_ci=0.2, min_runs=3, budget_s=0.5, max_runs=5, warmup=1,
                      warmup_s=0.0)
OPTIONS = {"threads": 1, "roofline": 1.0, "macs": 1}


class HalfFlipsInLowPrecision(nn.Module):
    """Logits whose left half of the image swaps its two classes when the convolution ran
    below fp32 (a variant that is wrong on half of the pixels)."""

    def __init__(self) -> None:
        super().__init__()
        self.conv = nn.Conv2d(3, 2, 1)
        with torch.no_grad():  # class 0 everywhere: a clear margin over class 1
            self.conv.weight.zero_()
            self.conv.bias.copy_(torch.tensor([1.0, -1.0]))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = self.conv(x)
        if y.dtype != torch.float32:
            left = y.shape[-1] // 2
            y = torch.cat([y[..., :left].flip(1), y[..., left:]], dim=-1)
        return y.float()


def _sweep(module, patterns, **kw):
    return backend_sweep("net", module, (torch.rand(1, 3, 8, 10),),
                         selected=select_variants(patterns), policy=POLICY,
                         **{**OPTIONS, **kw})


def test_gpu_only_variants_are_refused_in_one_line_on_the_cpu(tmp_path):
    sweep = _sweep(nn.Conv2d(3, 4, 3, padding=1),
                   ["cuda-graph-*", "compile-reduce-overhead-fp32", "onnxruntime-*"],
                   onnx={"cache_dir": tmp_path})
    ref = sweep.result(REFERENCE)
    assert (ref.status, ref.label_agreement, ref.qualifies, ref.speedup) == ("timed", 1.0, True,
                                                                             1.0)
    refused = [r for r in sweep.results if r.status == "refused"]
    assert {r.variant for r in refused} == {
        "cuda-graph-fp32", "cuda-graph-fp16", "cuda-graph-bf16",
        "cuda-graph-channels-last-fp32", "cuda-graph-channels-last-fp16",
        "cuda-graph-channels-last-bf16", "compile-reduce-overhead-fp32",
        "onnxruntime-cuda-fp32", "onnxruntime-tensorrt-fp32", "onnxruntime-tensorrt-fp16"}
    for r in refused:
        assert r.why and "\n" not in r.why and r.ms_median is None and not r.qualifies
    assert "needs a GPU" in sweep.result("cuda-graph-fp16").why
    assert "does not run on device cpu" in sweep.result("onnxruntime-cuda-fp32").why
    ort = sweep.result("onnxruntime-cpu-fp32")
    assert ort.status == "timed" and ort.label_agreement == 1.0  # the same labels, fp32
    assert sweep.fastest in {REFERENCE, "onnxruntime-cpu-fp32"}


def test_reduced_precision_labels_are_compared_with_eager_fp32s():
    sweep = _sweep(HalfFlipsInLowPrecision(), ["eager-bf16", "channels-last-fp32"])
    bf16 = sweep.result("eager-bf16")
    assert bf16.status == "timed" and bf16.label_agreement == pytest.approx(0.5)
    assert bf16.required_agreement == REDUCED_PRECISION_AGREEMENT and not bf16.qualifies
    assert sweep.result("channels-last-fp32").label_agreement == 1.0
    assert sweep.fastest != "eager-bf16"  # however fast, it does not keep the labels


def test_bf16_of_an_ordinary_network_keeps_its_labels_within_the_tolerance():
    torch.manual_seed(0)
    net = nn.Sequential(nn.Conv2d(3, 8, 3, padding=1), nn.ReLU(), nn.Conv2d(8, 5, 1))
    r = _sweep(net, ["eager-bf16"]).result("eager-bf16")
    assert 0.9 < r.label_agreement <= 1.0
    assert r.qualifies == (r.label_agreement >= REDUCED_PRECISION_AGREEMENT)


def test_a_variant_that_breaks_is_its_own_row_and_eager_fp32_is_not_optional():
    def measure(module, inputs, **kw):
        if kw["backend"].name == "torch" and kw["backend"].autocast == "bf16":
            raise RuntimeError("a kernel failed\nwith a second line")
        if kw["backend"].autocast == "fp16":
            raise torch.OutOfMemoryError("CUDA out of memory")
        return measure_speed(module, inputs, **kw)

    sweep = _sweep(nn.Conv2d(3, 4, 1), ["eager-bf16", "eager-fp16"], measure=measure)
    broken, oom = sweep.result("eager-bf16"), sweep.result("eager-fp16")
    assert (broken.status, broken.why) == ("failed", "RuntimeError: a kernel failed")
    assert oom.status == "refused" and oom.why.startswith("out of memory")
    assert sweep.fastest == REFERENCE
    with pytest.raises(DeviceUnavailableError):  # nothing to compare with
        _sweep(nn.Conv2d(3, 4, 1), ["eager-fp16"], device="cuda:7")


def _result(name: str, ms: float | None, qualifies: bool) -> VariantResult:
    return VariantResult(name, "torch", "fp32", None, False, None,
                         "timed" if ms is not None else "refused", ms_median=ms,
                         qualifies=qualifies)


def test_the_fastest_qualifying_variant_is_the_lowest_pass_among_those_that_qualify():
    results = [_result(REFERENCE, 10.0, True), _result("cuda-graph-fp16", 2.0, False),
               _result("cuda-graph-fp32", 4.0, True), _result("compile-default-fp32", 4.0, True),
               _result("refused", None, False)]
    assert fastest_qualifying(results).variant == "cuda-graph-fp32"  # the first of equals
    assert fastest_qualifying(results[:1]).variant == REFERENCE
    assert fastest_qualifying([results[1], results[4]]) is None


def test_variant_selection_and_labels():
    names = [v.name for v in variants()]
    assert names[0] == REFERENCE and len(names) == len(set(names))
    chosen = [v.name for v in select_variants(["*-fp16"])]
    assert chosen[0] == REFERENCE and "cuda-graph-fp16" in chosen
    assert all(n.endswith("-fp16") for n in chosen[1:])
    with pytest.raises(UnknownNameError, match="matches none"):
        select_variants(["cuda-graphs"])
    logits = torch.tensor([[[[0.0, 2.0]], [[1.0, 1.0]]]])  # (1, 2, 1, 2)
    assert argmax_labels((logits,)).tolist() == [[[1, 0]]]
    assert argmax_labels([logits.numpy()]).tolist() == [[[1, 0]]]
    assert label_agreement(torch.tensor([1, 0]), torch.tensor([1, 1])) == 0.5
    with pytest.raises(ValueError, match="shape"):
        label_agreement(torch.zeros(2), torch.zeros(3))
