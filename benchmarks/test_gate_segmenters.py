"""Performance gate: the project's speed goal for FEAGNet against ESANet-R34-NBt1D.

The goal, as frames per second on the CPU with ONNX Runtime at 640x480 (batch 1):

* FPS(feagnet-v2) / FPS(esanet-r34-nbt1d) >= 3
* FPS(feagnet-v1) / FPS(esanet-r34-nbt1d) >= 8

Only ratios of speeds measured in this one run are compared (never absolute figures, never
figures of another run), so the gate holds on any machine. The three networks are timed in
several short passes, in alternating orders, and each FPS is the median over all its passes, so
a change in the machine's load during the run biases no network in particular. The best
(minimum-latency) figures are printed as well: on a machine shared with other work they show
what the medians would be without interference. Runs only with ``--benchmark-only``
(``nox -s bench``); see ``benchmarks/conftest.py``.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

BASELINE = "esanet-r34-nbt1d"
GOALS = {"feagnet-v2": 3.0, "feagnet-v1": 8.0}  # minimum FPS ratio over the baseline
SIZE = (480, 640)
RUNS, WARMUP, PASSES = 6, 1, 3


def _measure(paper_network) -> dict[str, dict]:
    from evsmap.measure.complexity import measure_complexity
    from evsmap.measure.speed import measure_speed
    from evsmap.measure.speed_backends import OnnxRuntime
    from evsmap.measure.timing_policy import RoundsPolicy

    names = (BASELINE, *GOALS)
    nets = {}
    for name in names:
        seg = paper_network(name)  # seed-0 weights: the ONNX exports are cached (conftest.py)
        inputs = seg.example_inputs(*SIZE)
        nets[name] = (seg, inputs, measure_complexity(seg.module, inputs).flops)
    times: dict[str, list[float]] = {name: [] for name in names}
    for index in range(PASSES):
        for name in names if index % 2 == 0 else names[::-1]:
            seg, inputs, macs = nets[name]
            record = measure_speed(
                seg.module, inputs,
                backend=OnnxRuntime(input_names=tuple(seg.input_names), key=name),
                policy=RoundsPolicy(runs=RUNS, warmup=WARMUP), macs=macs,
                roofline_size=512)  # the gate needs no roofline; keep it cheap
            times[name].extend(record.times_ms)
    result = {}
    for name in names:
        ms = np.asarray(times[name])
        q25, median, q75 = np.percentile(ms, [25, 50, 75])
        result[name] = {"ms_median": float(median), "ms_iqr": float(q75 - q25),
                        "ms_min": float(ms.min()), "fps": float(1000.0 / median),
                        "fps_best": float(1000.0 / ms.min()), "macs": nets[name][2],
                        "samples": len(ms)}
    return result


@pytest.mark.gate
def test_feagnet_speed_goal_over_esanet(benchmark, capsys, paper_network):
    benchmark.group = "gate"
    result = benchmark.pedantic(_measure, args=(paper_network,), rounds=1, warmup_rounds=0,
                                iterations=1)
    base = result[BASELINE]["fps"]
    ratios = {name: result[name]["fps"] / base for name in GOALS}
    best = {name: result[name]["fps_best"] / result[BASELINE]["fps_best"] for name in GOALS}
    benchmark.extra_info.update(
        backend="onnxruntime", height=SIZE[0], width=SIZE[1], threads=torch.get_num_threads(),
        figures=result, ratios=ratios, best_ratios=best, goals=GOALS)
    lines = [f"speed gate (onnxruntime, {SIZE[1]}x{SIZE[0]}, {torch.get_num_threads()} threads, "
             f"{PASSES} x {RUNS} runs each)"]
    for name, r in result.items():
        lines.append(f"  {name:18s} {r['fps']:6.2f} FPS  {r['ms_median']:7.1f} ms median "
                     f"(IQR {r['ms_iqr']:6.1f}, best {r['ms_min']:6.1f} ms)  "
                     f"{r['macs'] / 1e9:5.2f} G MAC")
    for name, goal in GOALS.items():
        verdict = "ok" if ratios[name] >= goal else "BELOW GOAL"
        lines.append(f"  FPS({name}) / FPS({BASELINE}) = {ratios[name]:.2f}  "
                     f"(goal >= {goal:g}: {verdict}; best-case ratio {best[name]:.2f})")
    report = "\n".join(lines)
    with capsys.disabled():
        print("\n" + report)
    failed = [name for name, goal in GOALS.items() if ratios[name] < goal]
    assert not failed, f"speed goal not met by {', '.join(failed)}:\n{report}"
