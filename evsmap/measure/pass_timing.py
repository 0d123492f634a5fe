"""One definition of how a network's forward pass is timed, for ``evsmap speed``, the runner's
speed cells and the gate alike (:class:`PassTiming`), and where a pass's time goes.

The definition, recorded in every record as ``timing``:

* **host threads**: torch's intra-op threads (and ONNX Runtime's) while timing; on a GPU one by
  default, since the host only launches kernels (more threads only add pool wake-ups to a
  launch-bound pass), on the CPU the count asked for (default: torch's current one);
* **pinning**: the process is pinned to the lowest ``host_threads`` CPUs it may use while
  timing (the gate's rule: two cores of a VM can differ in speed, and a process that migrates
  between them mixes both), then unpinned;
* **stream and synchronisation**: on a GPU the pass is queued on the device's current stream,
  between two CUDA events, and the host waits for the second after every pass (a pass never
  overlaps the next); on the CPU the host's work is done when the call returns;
* **clock**: CUDA events on a GPU, the host's wall clock beside it (their medians both kept);
  the host clock on the CPU;
* **settle**: on a GPU, passes until the speed settles before any is timed
  (:func:`evsmap.devices.settle`: clocks ramp, cuDNN's autotuner tries its algorithms); cuDNN's
  autotuner on.

**Where the time goes** (:func:`device_busy`): the device-busy share of a pass is the time its
kernels keep the GPU busy (the union of their intervals, from torch's profiler) over the pass's
time; the host's dispatch time (until the call returns, before the synchronisation) is kept
beside. A pass whose GPU is busy less than :data:`LAUNCH_BOUND_SHARE` of it waits on the host's
launches: it is labelled ``launch``-bound (its time measures Python and the launch path, and
moves with the host); otherwise ``device``-bound; on the CPU the host does the work (``host``).
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Callable, Iterator, Sequence
from dataclasses import asdict, dataclass
from typing import Any

from evsmap.devices import device_name

LAUNCH_BOUND_SHARE = 0.5
"""Below this device-busy share a GPU pass is launch-bound: the GPU idles for most of it."""
BOUNDS = ("launch", "device", "host")
BUSY_PASSES = 5
"""Passes profiled for the device-busy share."""


@dataclass(frozen=True)
class PassTiming:
    """How a pass is timed (module docstring); :meth:`as_dict` is the records' ``timing``."""

    device: str
    host_threads: int
    cpus: tuple[int, ...] | None
    stream: str
    synchronisation: str
    clock: str
    settle: bool
    cudnn_benchmark: bool

    def as_dict(self) -> dict[str, Any]:
        out = asdict(self)
        out["cpus"] = list(self.cpus) if self.cpus is not None else None
        return out

    @contextlib.contextmanager
    def applied(self) -> Iterator[None]:
        """torch's threads and the process's CPUs as defined, restored after."""
        import torch

        previous = torch.get_num_threads()
        affinity = _affinity()
        try:
            torch.set_num_threads(self.host_threads)
            if self.cpus is not None and affinity is not None:
                os.sched_setaffinity(0, set(self.cpus))
            yield
        finally:
            torch.set_num_threads(previous)
            if self.cpus is not None and affinity is not None:
                os.sched_setaffinity(0, affinity)


def pass_timing(device: str = "cpu", threads: int | None = None, *,
                cpus: Sequence[int] | None = None, pin: bool = True) -> PassTiming:
    """The timing definition for ``device`` with ``threads`` host threads (default: one on a
    GPU, torch's current count on the CPU), pinned to ``cpus`` (default: the lowest
    ``threads`` CPUs this process may use; ``pin=False``: not pinned).

    Raises:
        UnknownNameError: a misspelt device.
        ValueError: fewer than one thread, or ``cpus`` not ones this process may use.
    """
    import torch

    name = device_name(device)
    gpu = name != "cpu"
    threads = threads if threads is not None else (1 if gpu else torch.get_num_threads())
    if threads < 1:
        raise ValueError(f"host threads must be >= 1, got {threads}")
    return PassTiming(
        device=name, host_threads=threads, cpus=_cpus(threads, cpus) if pin else None,
        stream="the device's current stream" if gpu else "host",
        synchronisation="the end event, after every pass" if gpu else
        "none (the host's work is done when the call returns)",
        clock="cuda events (host wall clock beside)" if gpu else "host clock",
        settle=gpu, cudnn_benchmark=gpu)


def _affinity() -> set[int] | None:
    return os.sched_getaffinity(0) if hasattr(os, "sched_getaffinity") else None


def _cpus(threads: int, cpus: Sequence[int] | None) -> tuple[int, ...] | None:
    allowed = _affinity()
    if allowed is None:
        return None
    if cpus is not None:
        bad = sorted(set(cpus) - allowed)
        if bad:
            raise ValueError(f"CPUs {bad} are not ones this process may use "
                             f"({', '.join(map(str, sorted(allowed)))})")
        return tuple(sorted(set(cpus)))
    return tuple(sorted(allowed)[:threads])


@dataclass(frozen=True)
class DeviceBusy:
    """Where a pass's time goes: ``kernel_ms`` the GPU was busy with the pass's kernels (the
    union of their intervals, per pass), ``busy_share`` that over the pass's time, ``bound``
    (:data:`BOUNDS`); ``why`` when the share could not be measured (then the others None)."""

    kernel_ms: float | None
    busy_share: float | None
    bound: str | None
    why: str | None = None

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


HOST = DeviceBusy(None, None, "host", None)
"""On the CPU: the host does the work; there is no device to be idle."""


def bound_of(busy_share: float | None) -> str | None:
    """``launch`` below :data:`LAUNCH_BOUND_SHARE`, ``device`` from it, None unknown."""
    if busy_share is None:
        return None
    return "launch" if busy_share < LAUNCH_BOUND_SHARE else "device"


def device_busy(call: Callable[[], object], pass_s: float, device: str,
                passes: int = BUSY_PASSES) -> DeviceBusy:
    """The device-busy share of ``call`` (one pass taking ``pass_s`` seconds as timed), from
    ``passes`` passes under torch's profiler; :data:`HOST` on the CPU."""
    if device_name(device) == "cpu":
        return HOST
    import torch
    from torch.profiler import ProfilerActivity, profile

    try:
        with profile(activities=[ProfilerActivity.CUDA]) as prof:
            for _ in range(passes):
                call()
            torch.cuda.synchronize(device)
        intervals = kernel_intervals(prof.events())
    except Exception as exc:  # noqa: BLE001 - a profiler that cannot run: the share is unknown
        return DeviceBusy(None, None, None, f"torch's profiler: {type(exc).__name__}: {exc}")
    if not intervals:
        return DeviceBusy(None, None, None, "the profiler recorded no GPU kernel")
    kernel_s = busy_seconds(intervals) / passes
    share = kernel_s / pass_s if pass_s > 0 else None
    return DeviceBusy(kernel_s * 1e3, share, bound_of(share))


def kernel_intervals(events: Any) -> list[tuple[float, float]]:
    """``(start, end)`` in microseconds of every GPU kernel among profiler ``events``
    (torch's ``FunctionEvent``: ``device_type`` CUDA, ``time_range``)."""
    from torch.autograd import DeviceType

    return [(float(e.time_range.start), float(e.time_range.end)) for e in events
            if e.device_type == DeviceType.CUDA and e.time_range.end > e.time_range.start]


def busy_seconds(intervals: Sequence[tuple[float, float]]) -> float:
    """Seconds covered by the union of ``intervals`` (microseconds; kernels of several
    streams overlap and count once)."""
    total, end = 0.0, float("-inf")
    for start, stop in sorted(intervals):
        if stop <= end:
            continue
        total += stop - max(start, end)
        end = stop
    return total / 1e6
