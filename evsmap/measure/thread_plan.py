"""The pipelined mapping loop's threads, planned from the cores it may use and the device its
network runs on (``evsmap map --cores N``; recorded as the map record's ``thread_plan``).

:func:`thread_plan` is a pure function of ``(cores, device)``. The pipelined loop
(:mod:`evsmap.measure.pipelined`) runs three Python threads: the reader, the segmentation
(pre-processing, the network, post-processing, one after the other) and the update. Its rate is
bounded by its slowest stage, so the plan gives each stage the cores its work can use and no
more; thread pools larger than the cores left to them only take cores from the other stages.

The rule, stage by stage (``c`` cores):

* ``read``: 1. One Python thread; PIL's decoders use no pool. Not a setting; recorded.
* ``blas``: 1. No stage's heavy work is a BLAS call; the one product in the loop (a 307,200 x 3
  by 3 x 3 ray product) is memory-bound, and OpenBLAS's pool busy-waits for the cores the
  other stages hold (1 ms alone, 200 ms in the pipeline with two threads: docs/realtime.md).
* ``spinning``: off. ONNX Runtime's idle workers would busy-wait between operators on cores the
  reader and the update need.
* On the **CPU**:

  - ``segment`` (the network's intra-op threads): ``None``, the sequential loop's count (torch's
    default, the cores it sees). The network's logits depend on this count in their last bits
    (docs/cli.md, "Thread independence"), so the pipeline keeps it whatever the cores: the
    pipelined and the sequential loop write the same map bytes. The price: while the network
    runs, its pool shares the cores with the update.
  - ``update``: ``max(1, (c - 1) // 3)``: a third of the cores beyond the reader's. On the CPU
    the segmentation is the heaviest stage, about two to three times the update's CPU time a
    frame (network and top-k against the update, docs/realtime.md, "Measured"); the update's
    results do not depend on its threads (:mod:`evsmap.mapping.threads`).
  - ``torch`` (pre- and post-processing): ``max(1, c - 1 - update)``: the cores the reader and the
    update leave. The top-k runs between two network passes in the segmentation thread, so
    it never competes with the network's own pool; it splits pixels, never a pixel's classes,
    across threads (the same bits at any count).

  With ``c = 2`` (and 1) this is :data:`~evsmap.measure.pipelined.PIPELINED`, the plan the
  2-core machines were measured with: update 1, torch 1.
* On a **GPU** (``cuda:N``):

  - ``segment``: 1. The forward pass runs on the GPU; its host side is one thread launching
    kernels, and its results do not depend on host threads.
  - ``torch``: 1. The host's share of the segmentation is a few elementwise operations of the
    pre-processing (its resize is evsmap's single-threaded kernel) and the copy of the top-k
    from the GPU; the faithful post-processing runs on the GPU (``--stage-threads torch=N``
    for the host top-k of ``-s postprocess=fused|stride``).
  - ``update``: ``max(1, c - 2)``: every core but the reader's and the segmentation thread's.
    The update is the heaviest host stage there (25.5 ms a frame on one thread on a 16-core
    GPU host, against 28 ms of segmentation).

Plans are recorded with a reason per stage (:meth:`ThreadPlan.as_dict`); ``--stage-threads
KEY=N`` overrides single stages on top of the plan, and the reason says so.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field, replace
from typing import Any

from evsmap.errors import InvalidDataError
from evsmap.measure.pipelined import SEQUENTIAL, StageThreads

MAX_CORES = 1024
"""The most cores a plan is made for (a larger ``--cores`` is a typo, and its pools would
start that many threads on this machine)."""

STAGES = ("read", "segment", "spinning", "torch", "update", "blas")
"""The settings a plan records, in the loop's order."""


@dataclass(frozen=True)
class ThreadPlan:
    """The threads of a mapping loop, and why.

    Attributes:
        cores: the cores the plan is for.
        device: where the network runs (``cpu`` or ``cuda:N``).
        pipelined: whether the plan is the pipelined loop's (else the sequential loop's:
            every library's default).
        threads: what the loop applies (:class:`~evsmap.measure.pipelined.StageThreads`).
        reasons: one sentence per stage in :data:`STAGES`.
        cores_from: where ``cores`` came from (``--cores`` or this process's CPUs).
    """

    cores: int
    device: str
    pipelined: bool
    threads: StageThreads
    reasons: dict[str, str] = field(default_factory=dict)
    cores_from: str = "this process's CPUs (os.sched_getaffinity)"

    def overridden(self, changes: dict[str, int]) -> ThreadPlan:
        """The plan with ``changes`` (``--stage-threads`` pairs, already checked) applied."""
        if not changes:
            return self
        reasons = dict(self.reasons)
        for key, n in changes.items():
            planned = getattr(self.threads, key)
            reasons[key] = f"--stage-threads {key}={n} (the plan: {_shown(planned)})"
        return replace(self, threads=self.threads.changed(changes), reasons=reasons)

    def as_dict(self) -> dict[str, Any]:
        """``cores``, ``cores_from``, ``device``, ``loop``, each stage's ``threads`` and
        ``reason`` under ``stages`` (``threads`` ``None``: the library's default of the moment)
        and ONNX Runtime's ``spinning`` (``enabled``, ``reason``)."""
        values = {"read": 1, **{k: getattr(self.threads, k) for k in STAGES if k != "read"}}
        return {"cores": self.cores, "cores_from": self.cores_from, "device": self.device,
                "loop": "pipelined" if self.pipelined else "sequential",
                "stages": {k: {"threads": values[k], "reason": self.reasons[k]}
                           for k in STAGES if k != "spinning"},
                "spinning": {"enabled": self.threads.spinning,
                             "reason": self.reasons["spinning"]}}


def available_cores() -> int:
    """The cores this process may run on (its CPU affinity; ``os.cpu_count`` where the
    platform has none)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        return os.cpu_count() or 1


def checked_cores(cores: object) -> int:
    """``cores`` as a core count for a plan.

    Raises:
        InvalidDataError: not an integer from 1 to :data:`MAX_CORES`.
    """
    if isinstance(cores, bool) or not isinstance(cores, int) or not 1 <= cores <= MAX_CORES:
        raise InvalidDataError(f"--cores {cores}: plan for 1 to {MAX_CORES} cores, please")
    return cores


def thread_plan(cores: int, device: str = "cpu", *, pipelined: bool = True) -> ThreadPlan:
    """The loop's threads for ``cores`` cores with the network on ``device`` (the rule: the
    module's docstring). ``pipelined=False``: the sequential loop's (every library's default:
    each stage alone has the cores), whatever the cores and device.

    Raises:
        InvalidDataError: ``cores`` outside 1 to :data:`MAX_CORES`.
        UnknownNameError: a misspelt device.
    """
    from evsmap.devices import device_name

    cores, device = checked_cores(cores), device_name(device)
    if not pipelined:
        return ThreadPlan(cores, device, False, SEQUENTIAL, _sequential_reasons())
    common = {
        "read": "one Python thread (PIL's decoders use no pool)",
        "blas": "no stage's heavy work is a BLAS call; OpenBLAS's pool busy-waits for cores "
                "the other stages hold",
        "spinning": "off: idle ONNX Runtime workers would busy-wait on cores the reader and "
                    "the update need",
    }
    if device == "cpu":
        return _cpu_plan(cores, common)
    return _gpu_plan(cores, device, common)


def _cpu_plan(cores: int, common: dict[str, str]) -> ThreadPlan:
    update = max(1, (cores - 1) // 3)
    torch = max(1, cores - 1 - update)
    reasons = {
        **common,
        "segment": "the sequential loop's count (torch's default, the cores it sees): the "
                   "network's logits depend on it, so both loops write the same map bytes",
        "update": f"a third of the {cores - 1} core(s) beyond the reader's, at least 1: on "
                  f"the CPU the segmentation is the heavier stage (2-3x the update's CPU "
                  f"time a frame)",
        "torch": f"the {cores} core(s) less the reader's and the update's, at least 1: the "
                 f"top-k runs between network passes, beside the update",
    }
    threads = StageThreads(segment=None, spinning=False, torch=torch, update=update, blas=1)
    return ThreadPlan(cores, "cpu", True, threads, _ordered(reasons))


def _gpu_plan(cores: int, device: str, common: dict[str, str]) -> ThreadPlan:
    update = max(1, cores - 2)
    reasons = {
        **common,
        "segment": f"1: the network runs on {device}; its host side is one launching thread "
                   f"and its results do not depend on host threads",
        "torch": "1: the host's share of the segmentation is the pre-processing's few "
                 "elementwise operations and the top-k's copy from the GPU",
        "update": f"the {cores} core(s) less the reader's and the segmentation thread's, at "
                  f"least 1: the update is the heaviest host stage beside a GPU network",
    }
    threads = StageThreads(segment=1, spinning=False, torch=1, update=update, blas=1)
    return ThreadPlan(cores, device, True, threads, _ordered(reasons))


def _sequential_reasons() -> dict[str, str]:
    alone = "the sequential loop: each stage runs alone, with the library's default"
    return {k: "one Python thread" if k == "read" else alone for k in STAGES}


def _ordered(reasons: dict[str, str]) -> dict[str, str]:
    return {k: reasons[k] for k in STAGES}


def _shown(value: object) -> str:
    return "the library's default" if value is None else str(value)
