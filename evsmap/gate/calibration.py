"""The calibration workload a gate divides every time by.

Two fixed parts, each about 5 ms on one core of the 2-core EPYC VM: dense fp32 arithmetic
(twelve 256x256 torch matmuls, what the networks do) and a memory-bound numpy pass (copying and
sorting 131,072 floats, like the map updaters' key sorts). A machine that runs faster or slower -
another CPU of the same kind, turbo, a noisy neighbour on a shared host - moves the
calibration and the workload together, so their ratio stays put.

One calibration is each part run three times back to back, keeping each part's fastest run: the
first run after a large workload finds its caches cold (and, after a workload that leaves many
Python objects, pays for a garbage collection), which says more about the workload just run than
about the machine. A third part, interpreted Python (dict work, like the readers and the
report), was dropped: measured over three processes of six workloads on this VM, it moved
10-32 % between processes where the two parts kept moved 1-12 % (docs/gates.md, "Calibration").

Every buffer is allocated once, before the workload's memory is measured, so timing the
calibration adds nothing to a workload's peak.
"""

from __future__ import annotations

import time

import numpy as np
import torch

MATMUL_SIZE = 256
MATMUL_REPEATS = 12
SORT_SIZE = 1 << 17
REPEATS = 3


class Calibration:
    """``run()`` times the calibration once and returns its seconds (the sum of each part's
    fastest of :data:`REPEATS` runs); ``parts`` holds those per-part seconds of the last call
    (``matmul``, ``sort``)."""

    def __init__(self) -> None:
        gen = torch.Generator().manual_seed(0)
        self._a = torch.randn(MATMUL_SIZE, MATMUL_SIZE, generator=gen)
        self._b = torch.randn(MATMUL_SIZE, MATMUL_SIZE, generator=gen)
        self._out = torch.empty(MATMUL_SIZE, MATMUL_SIZE)
        self._src = np.random.default_rng(0).random(SORT_SIZE, dtype=np.float32)
        self._buf = np.empty_like(self._src)
        self.parts: dict[str, float] = {}

    def _matmul(self) -> None:
        for _ in range(MATMUL_REPEATS):
            torch.matmul(self._a, self._b, out=self._out)

    def _sort(self) -> None:
        self._buf[:] = self._src
        self._buf.sort()

    def run(self) -> float:
        best = {"matmul": float("inf"), "sort": float("inf")}
        for _ in range(REPEATS):
            t0 = time.perf_counter()
            self._matmul()
            t1 = time.perf_counter()
            self._sort()
            t2 = time.perf_counter()
            best["matmul"] = min(best["matmul"], t1 - t0)
            best["sort"] = min(best["sort"], t2 - t1)
        self.parts = best
        return sum(best.values())
