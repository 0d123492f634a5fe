"""The calibration workload a gate divides every time by.

Three fixed parts, each a few milliseconds on one core: dense fp32 arithmetic (torch matmul,
what the networks do), a memory-bound numpy pass (sorting 131,072 floats, like the map
updaters' key sorts) and interpreted Python (dict and loop work, like readers and the report).
A machine that runs faster or slower - another CPU of the same kind, turbo, a noisy neighbour
on a shared host - moves the calibration and the workload together, so their ratio stays put.
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
PYTHON_ITEMS = 15_000


class Calibration:
    """``run()`` times the calibration once and returns its seconds; ``parts`` holds the
    seconds of each part of the last run (``matmul``, ``sort``, ``python``)."""

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

    @staticmethod
    def _python() -> None:
        table: dict[int, int] = {}
        for i in range(PYTHON_ITEMS):
            table[(i * 7919) % 10007] = table.get(i % 101, 0) + i
        sorted(table.items())

    def run(self) -> float:
        t0 = time.perf_counter()
        self._matmul()
        t1 = time.perf_counter()
        self._sort()
        t2 = time.perf_counter()
        self._python()
        t3 = time.perf_counter()
        self.parts = {"matmul": t1 - t0, "sort": t2 - t1, "python": t3 - t2}
        return t3 - t0
