"""int8 against fp32, measured the same way wherever it is reported: the runner's "int8 beside
fp32" section (:mod:`evsmap.runner.int8`) and the realtime benchmark
(``benchmarks/test_bench_realtime.py``).

* :func:`int8_pair` - a network in fp32 and in int8 with the same weights, each scheme
  calibrated on the given frames. An untrained (seeded) network first gets BatchNorm statistics
  of the calibration frames (:func:`~evsmap.segmenters.quantize.reestimate_batchnorm`): with the
  initial statistics every pixel has the same class and agreement reads a meaningless 100 %.
* :func:`alternating_ms` - the forward pass of each side on one input, the sides alternating
  run by run (forward, then reversed) so that a shared machine's drift hits all alike.
* :func:`spread` - median and IQR of a list of milliseconds.
* top-1 agreement: :func:`evsmap.segmenters.quantize.top1_agreement`.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np


def int8_pair(make: Callable[[], Any], calibration: Sequence[Any], *,
              schemes: Sequence[str] = ("auto",), source: str = "",
              untrained: bool = True) -> tuple[Any, dict[str, Any]]:
    """``(fp32, {scheme: int8})``: ``make()`` builds each (a network segmenter on ONNX
    Runtime); the int8 ones load the fp32 one's state (after the BatchNorm re-estimation when
    ``untrained``) and are calibrated on ``calibration``."""
    from evsmap.segmenters.quantize import reestimate_batchnorm

    fp32 = make()
    if untrained:
        reestimate_batchnorm(fp32.module, [fp32.preprocess(f) for f in calibration])
    int8 = {}
    for scheme in schemes:
        seg = make()
        seg.module.load_state_dict(fp32.module.state_dict())
        seg.calibrate(calibration, scheme=scheme, source=source)
        int8[scheme] = seg
    return fp32, int8


def alternating_ms(sides: Mapping[str, Any], frame: Any, runs: int) -> dict[str, list[float]]:
    """Milliseconds of each side's forward pass (``logits``) on ``frame``'s preprocessed
    input, ``runs`` each, the order of the sides reversed every other run, after one untimed
    pass each (sessions built)."""
    names = list(sides)
    inputs = sides[names[0]].preprocess(frame)
    for seg in sides.values():
        seg.logits(inputs)
    ms: dict[str, list[float]] = {k: [] for k in names}
    for r in range(runs):
        for name in (names if r % 2 == 0 else names[::-1]):
            t0 = time.perf_counter()
            sides[name].logits(inputs)
            ms[name].append((time.perf_counter() - t0) * 1e3)
    return ms


def spread(ms: Sequence[float]) -> dict[str, float]:
    """``{"ms_median", "ms_iqr", "runs"}`` of ``ms``."""
    q1, med, q3 = np.percentile(ms, [25, 50, 75])
    return {"ms_median": float(med), "ms_iqr": float(q3 - q1), "runs": len(ms)}
