"""Speed of the registered segmentation networks on the CPU at their paper resolution.

One forward pass (batch 1) of each network on its ``example_inputs`` with torch (eval,
``inference_mode``) and with ONNX Runtime (CPU provider, all graph optimisations, a session over
the cached ONNX export, as ``evsmap speed --backend onnxruntime`` runs it), plus ``predict`` end
to end for FEAGNet-V2 on a rendered 640x480 frame. Parameters, FLOPs (fvcore MACs) and the fp32
matmul roofline of the backend go into ``extra_info`` of the saved JSON.

The networks keep their random initial weights, drawn from seed 0 (the ``paper_network``
fixture of ``conftest.py``), so the ONNX exports are cached across runs.

On a machine whose cores are shared with other work, torch's and ONNX Runtime's thread pools
(which spin-wait for each other at every operator) slow down many times over whenever another
process takes a core; read the IQR and max columns before comparing medians.
"""

from __future__ import annotations

import pytest
import torch

from evsmap.registry import READERS

NETWORKS = ("feagnet-v1", "feagnet-v2", "feagnet-s", "feagnet-l", "esanet-r34-nbt1d",
            "fchardnet-70")
BACKENDS = ("torch", "onnxruntime")
# (rounds, warm-up rounds); rough torch / onnxruntime seconds per pass on 2 cores in brackets
ROUNDS = {
    "feagnet-v1": (15, 2),  # 0.09 / 0.11
    "feagnet-v2": (10, 2),  # 0.19 / 0.35
    "feagnet-s": (15, 2),  # 0.07
    "feagnet-l": (8, 1),  # 0.21
    "esanet-r34-nbt1d": (5, 1),  # 0.66 / 0.43
    "fchardnet-70": (10, 2),  # 0.12
}


@pytest.fixture(scope="module")
def network(paper_network):
    """``network(name)``: the segmenter, its paper-size inputs and its complexity (cached)."""
    from evsmap.measure.complexity import measure_complexity

    cache: dict[str, tuple] = {}

    def get(name: str):
        if name not in cache:
            seg = paper_network(name)
            inputs = seg.example_inputs(*seg.default_size)
            cache[name] = (seg, inputs, measure_complexity(seg.module, inputs))
        return cache[name]

    return get


@pytest.fixture(scope="module")
def roofline():
    """``roofline(backend)``: fp32 4096^3 matmul throughput, G MAC/s (measured once each)."""
    from evsmap.measure.speed import roofline_gmacs

    cache: dict[str, float] = {}

    def get(backend: str) -> float:
        if backend not in cache:
            cache[backend] = roofline_gmacs(backend=backend)
        return cache[backend]

    return get


def _ort_session(seg, inputs, key: str):
    import onnxruntime as ort

    from evsmap.models.onnx_export import cached_onnx

    path = cached_onnx(seg.module, inputs, seg.input_names, key=key)
    options = ort.SessionOptions()
    options.intra_op_num_threads = torch.get_num_threads()
    options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    options.log_severity_level = 3
    session = ort.InferenceSession(str(path), sess_options=options,
                                   providers=["CPUExecutionProvider"])
    arrays = dict(zip(seg.input_names, (t.numpy() for t in inputs), strict=True))
    return session, {i.name: arrays[i.name] for i in session.get_inputs()}


def _median_s(benchmark) -> float | None:
    stats = getattr(benchmark, "stats", None)  # None under --benchmark-disable
    return float(stats.stats.median) if stats is not None else None


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("name", NETWORKS)
def test_forward_pass(benchmark, network, roofline, name, backend):
    seg, inputs, complexity = network(name)
    height, width = seg.default_size
    rounds, warmup = ROUNDS[name]
    benchmark.group = "forward pass at the paper resolution"
    benchmark.extra_info.update(
        model=name, backend=backend, height=height, width=width,
        num_classes=seg.num_classes, threads=torch.get_num_threads(),
        params=complexity.params, macs=complexity.flops)
    module = seg.module.eval()
    if backend == "torch":
        with torch.inference_mode():
            out = benchmark.pedantic(module, args=inputs, rounds=rounds,
                                     warmup_rounds=warmup, iterations=1)
        shape = tuple(out.shape)
    else:
        session, feeds = _ort_session(seg, inputs, key=name)
        out = benchmark.pedantic(session.run, args=(None, feeds), rounds=rounds,
                                 warmup_rounds=warmup, iterations=1)
        shape = out[0].shape
    assert shape == (1, seg.num_classes, height, width)
    ceiling = roofline(backend)
    benchmark.extra_info["roofline_gmacs"] = ceiling
    median = _median_s(benchmark)
    if median:
        achieved = complexity.flops / median / 1e9
        benchmark.extra_info.update(fps=1.0 / median, achieved_gmacs=achieved,
                                    roofline_fraction=achieved / ceiling)


@pytest.mark.parametrize("backend", BACKENDS)
def test_predict_feagnet_v2_640x480(benchmark, paper_network, backend):
    frame = READERS.create("synthetic", frames=1)[0]
    assert (frame.height, frame.width) == (480, 640)
    seg = paper_network("feagnet-v2", backend=backend)
    benchmark.group = "predict end to end"
    benchmark.extra_info.update(model="feagnet-v2", backend=backend, height=480, width=640,
                                k=3, threads=torch.get_num_threads())
    seg.predict(frame)  # exports the network (onnxruntime) outside the timing
    obs = benchmark.pedantic(seg.predict, args=(frame,), rounds=10, warmup_rounds=2,
                             iterations=1)
    assert obs.shape == (480, 640) and obs.k == 3
    median = _median_s(benchmark)
    if median:
        benchmark.extra_info["fps"] = 1.0 / median
