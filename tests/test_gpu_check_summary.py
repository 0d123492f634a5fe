"""benchmarks/gpu_check.py's table from recorded steps (no step run): the timer agreement read
from the gate's JSON, the backend sweep's fastest variant marked, the FEAGNet / ESANet ratios,
a failed or skipped step said in its row."""

from __future__ import annotations

import argparse

from benchmarks import gpu_check


def _sweep(net, eager_ms, graph_ms):
    timed = {"status": "timed", "label_agreement": 1.0, "qualifies": True, "bound": "launch",
             "compile_s": None}
    return {"exit": 0, "result": {"network": net, "fastest": "cuda-graph-fp32", "results": [
        {**timed, "variant": "eager-fp32", "ms_median": eager_ms, "speedup": 1.0},
        {**timed, "variant": "cuda-graph-fp32", "ms_median": graph_ms,
         "speedup": eager_ms / graph_ms},
        {"variant": "onnxruntime-tensorrt-fp16", "status": "refused",
         "why": "--provider tensorrt: not installed"}]}}


def test_the_table_reads_every_step():
    records = {
        "environment": {"gpu": {"gpu": "NVIDIA H200", "clocks_sm": 1980, "clocks_max_sm": 1980},
                        "cuda": "13.0", "torch": "2.11"},
        "a/speed/feagnet-v2": {"exit": 0, "result": {"ms_median": 10.4, "busy": {"bound":
                                                                               "launch"}}},
        "a/gate": {"exit": 1, "result": {"workloads": {"net/feagnet-v2/torch": [
            {"name": "net/feagnet-v2/torch", "workload_ms": 10.0}]}}},
        "b/sweep/feagnet-v2": _sweep("feagnet-v2", 12.0, 3.0),
        "b/sweep/esanet-r34-nbt1d": _sweep("esanet-r34-nbt1d", 24.0, 9.0),
        "c/batch/feagnet-v2": {"skipped": "out of time"},
    }
    text = gpu_check.summary(records, argparse.Namespace(device="cuda"))
    assert "NVIDIA H200 (SM clock 1980 of 1980 MHz" in text
    assert "| a | feagnet-v2: speed vs gate (1 host thread), ms | 10.40 vs 10.00 (+4.0 %) | " \
           "within the 5 % goal" in text
    assert "**fastest with eager fp32's labels**" in text
    assert "| b | feagnet-v2 / esanet-r34-nbt1d speed, eager-fp32 | 2.00 | paper 2.81 |" in text
    assert "| b | feagnet-v2 / esanet-r34-nbt1d speed, cuda-graph-fp32 | 3.00 |" in text
    assert "refused: --provider tensorrt: not installed" in text
    assert "| c | feagnet-v2: batch sweep | skipped: out of time |" in text
    assert gpu_check.gate_workload_ms(records["a/gate"]["result"], "net/x/torch") is None
