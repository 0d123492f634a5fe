"""int8 against fp32 on ONNX Runtime (issue 20): network milliseconds and argmax agreement.

For each network: seeded weights with BatchNorm statistics re-estimated on synthetic frames
(:func:`evsmap.segmenters.quantize.reestimate_batchnorm`), fp32 and int8 (u8s8, s8s8)
sessions at the given size and thread count, timed in interleaved rounds (so drift of a shared
machine hits all three alike), and the argmax agreement of each int8 model with fp32 on
held-out synthetic frames (odd indices; calibration uses even ones). One JSON line per network.

    python benchmarks/int8_speed.py feagnet-v1 feagnet-v2 --size 480x640 --threads 2
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import time

import numpy as np
import torch

from evsmap.registry import SEGMENTERS
from evsmap.segmenters.quantize import evenly_spaced, reestimate_batchnorm
from evsmap.synth.sequence import SyntheticSequence


def _session(path: str, threads: int):
    import onnxruntime as ort

    options = ort.SessionOptions()
    options.intra_op_num_threads = threads
    options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    return ort.InferenceSession(path, options, providers=["CPUExecutionProvider"])


def measure(name: str, *, size: tuple[int, int], threads: int, calibration: int,
            held_out: int, rounds: int, auto_exclude: int) -> dict:
    torch.manual_seed(0)
    torch.set_num_threads(threads)
    sequence = SyntheticSequence()
    base = SEGMENTERS.create(name, backend="onnxruntime", input_size=size)
    even = list(range(0, len(sequence), 2))
    reestimate_batchnorm(base.module, [base.preprocess(sequence.frame(i)) for i in even[::3]])
    cal = [sequence.frame(even[i]) for i in evenly_spaced(len(even), calibration)]
    odd = [1 + 2 * i for i in evenly_spaced(len(sequence) // 2, held_out)]
    tests = [base.preprocess(sequence.frame(i)) for i in odd]
    feeds = [{n: t.numpy() for n, t in zip(base.input_names, x, strict=True)} for x in tests]
    paths = {"fp32": str(base._fp32_onnx(tests[0]))}
    out: dict = {"model": name, "size": list(size), "threads": threads,
                 "calibration_frames": len(cal), "held_out_frames": len(odd)}
    for scheme in ("u8s8", "s8s8"):
        t0 = time.perf_counter()
        q = base.calibrate(cal, scheme=scheme, auto_exclude=auto_exclude,
                           source="synthetic even frames")
        out[f"{scheme}_quantise_s"] = round(time.perf_counter() - t0, 1)
        out[f"{scheme}_fp32_nodes"] = len(q.excluded)
        out[f"{scheme}_auto"] = q.auto_ranking
        paths[scheme] = str(q.path)
    sessions = {k: _session(p, threads) for k, p in paths.items()}
    inputs = {k: [{i.name: f[i.name] for i in s.get_inputs()} for f in feeds]
              for k, s in sessions.items()}
    logits = {k: [s.run(None, f)[0] for f in inputs[k]] for k, s in sessions.items()}
    for scheme in ("u8s8", "s8s8"):
        agree = [float((a.argmax(1) == b.argmax(1)).mean())
                 for a, b in zip(logits[scheme], logits["fp32"], strict=True)]
        out[f"{scheme}_agreement_median"] = round(float(np.median(agree)), 4)
        out[f"{scheme}_agreement_min"] = round(min(agree), 4)
    times: dict[str, list[float]] = {k: [] for k in sessions}
    for _ in range(rounds):
        for k, s in sessions.items():
            s.run(None, inputs[k][0])  # warm
            for _ in range(3):
                t = time.perf_counter()
                s.run(None, inputs[k][0])
                times[k].append((time.perf_counter() - t) * 1e3)
    for k, v in times.items():
        q25, med, q75 = np.percentile(v, [25, 50, 75])
        out[f"{k}_ms_median"], out[f"{k}_ms_iqr"] = round(float(med), 1), round(float(q75 - q25), 1)
    for scheme in ("u8s8", "s8s8"):
        out[f"{scheme}_speedup"] = round(out["fp32_ms_median"] / out[f"{scheme}_ms_median"], 2)
    out["load_after"] = os.getloadavg()[0]
    return out


def main() -> None:
    logging.getLogger().setLevel(logging.ERROR)
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("models", nargs="+")
    p.add_argument("--size", default="480x640")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--calibration", type=int, default=8)
    p.add_argument("--held-out", type=int, default=4)
    p.add_argument("--rounds", type=int, default=5)
    p.add_argument("--auto-exclude", type=int, default=0)
    args = p.parse_args()
    h, w = (int(v) for v in args.size.split("x"))
    for name in args.models:
        print(json.dumps(measure(name, size=(h, w), threads=args.threads,
                                 calibration=args.calibration, held_out=args.held_out,
                                 rounds=args.rounds, auto_exclude=args.auto_exclude)),
              flush=True)


if __name__ == "__main__":
    main()
