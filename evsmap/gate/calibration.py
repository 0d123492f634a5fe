"""The calibration workloads a gate divides every time by.

A machine that runs faster or slower - another CPU of the same kind, turbo, a noisy neighbour
on a shared host - moves the calibration and the workload together, so their ratio stays put.
Workloads do not all move alike, so there are two calibrations (:data:`KINDS`):

- ``compute``, for the networks, the end-to-end map and the TUM reader (PNG decoding): dense
  fp32 arithmetic (twelve 256x256 torch matmuls) and copying and sorting 131,072 floats, both
  resident in the 2 MiB L2, about 5 and 4 ms on one core of the 2-core EPYC VM;
- ``memory``, for the map updaters, the ROS bag reader and the report: a random gather of
  1,048,576 floats from a 64 MiB table, beyond the 32 MiB L3 that the VM shares with its host's
  other tenants, about 11 ms: what octree and hash-table lookups do.

Over a 10-run study these workloads slowed 1.5-2.3 times as much as the ``compute`` calibration
whenever the host slowed (their time's elasticity to it; the networks' was about 1), so their
ratios rose in every slow spell (docs/gates.md, "Calibration").

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
GATHER_TABLE = 1 << 24  # floats: 64 MiB
GATHER_SIZE = 1 << 20
REPEATS = 3
GPU_MATMUL_SIZE = 2048
GPU_MATMUL_REPEATS = 8
KINDS = {"compute": ("matmul", "sort"), "memory": ("gather",), "gpu": ("gpu_matmul",)}


class Calibration:
    """``run()`` times the calibration once and returns its seconds (the sum of each part's
    fastest of :data:`REPEATS` runs); ``parts`` holds those per-part seconds of the last call.

    Args:
        kind: ``"compute"`` (parts ``matmul`` and ``sort``), ``"memory"`` (``gather``) or
            ``"gpu"`` (``gpu_matmul``: eight 2048x2048 fp32 matmuls on ``device``, a GPU,
            timed between CUDA events, for the workloads that run there).
        device: the GPU of the ``gpu`` kind.
    """

    def __init__(self, kind: str = "compute", device: str = "cuda") -> None:
        if kind not in KINDS:
            raise ValueError(f"calibration kind {kind!r}: one of {', '.join(KINDS)}")
        self.kind = kind
        self._names = KINDS[kind]
        gen = torch.Generator().manual_seed(0)
        rng = np.random.default_rng(0)
        if "matmul" in self._names:
            self._a = torch.randn(MATMUL_SIZE, MATMUL_SIZE, generator=gen)
            self._b = torch.randn(MATMUL_SIZE, MATMUL_SIZE, generator=gen)
            self._out = torch.empty(MATMUL_SIZE, MATMUL_SIZE)
        if "sort" in self._names:
            self._src = rng.random(SORT_SIZE, dtype=np.float32)
            self._buf = np.empty_like(self._src)
        if "gpu_matmul" in self._names:
            from evsmap.devices import PassTimer

            self._ga = torch.randn(GPU_MATMUL_SIZE, GPU_MATMUL_SIZE, generator=gen).to(device)
            self._gb = torch.randn(GPU_MATMUL_SIZE, GPU_MATMUL_SIZE, generator=gen).to(device)
            self._gout = torch.empty_like(self._ga)
            self._timer = PassTimer(device)
        if "gather" in self._names:
            self._table = rng.random(GATHER_TABLE, dtype=np.float32)
            self._index = rng.integers(0, GATHER_TABLE, GATHER_SIZE).astype(np.int32)
            self._picked = np.empty(GATHER_SIZE, np.float32)
        self.parts: dict[str, float] = {}

    def _matmul(self) -> None:
        for _ in range(MATMUL_REPEATS):
            torch.matmul(self._a, self._b, out=self._out)

    def _sort(self) -> None:
        self._buf[:] = self._src
        self._buf.sort()

    def _gpu_matmul(self) -> None:
        for _ in range(GPU_MATMUL_REPEATS):
            torch.matmul(self._ga, self._gb, out=self._gout)

    def _gather(self) -> None:
        np.take(self._table, self._index, out=self._picked)

    def run(self) -> float:
        best = dict.fromkeys(self._names, float("inf"))
        for _ in range(REPEATS):
            for name in self._names:
                part = getattr(self, f"_{name}")
                if name == "gpu_matmul":
                    best[name] = min(best[name], self._timer(part))
                    continue
                t = time.perf_counter()
                part()
                best[name] = min(best[name], time.perf_counter() - t)
        self.parts = best
        return sum(best.values())
