"""Where a network runs: the ``--device`` option's values, their checks, and how one pass is
timed there.

A device is spelled ``cpu``, ``cuda`` or ``cuda:N`` (torch's spelling; ``cuda`` is ``cuda:0``).
:func:`device_name` checks the spelling only (the command-line parser uses it, so building the
parser imports nothing heavy); :func:`require_device` also checks that this machine has it and
says in one line why not (this torch has no CUDA, no GPU is visible, no GPU of that index).

Timing on a GPU is what GPU people do (:class:`PassTimer`): the pass between two CUDA events on
the current stream, then a synchronisation on the second, so the time is the GPU's, not the
launch's; on the CPU the host clock. :func:`settle` warms a device up until its clocks settle:
passes until the median of the last window is within a tolerance of the window before (a GPU
ramps its clocks for the first second or two of load, and cudnn's autotuner tries its
algorithms in the first passes of each shape).

The GPU's facts (model, driver, CUDA, clocks) are machine facts and live in
:func:`evsmap.environment.collect_gpu`.
"""

from __future__ import annotations

import re
import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from evsmap.errors import EvsmapError, UnknownNameError

if TYPE_CHECKING:
    import torch

DEVICE_PATTERN = re.compile(r"^(cpu|cuda)(?::(\d+))?$")
DEVICES_HELP = "cpu (default), cuda or cuda:N (an NVIDIA GPU through torch's CUDA build)"


class DeviceUnavailableError(EvsmapError):
    """The device named is well spelled but this machine or this build cannot run on it."""


def device_name(text: str) -> str:
    """The canonical spelling of device ``text``: ``cpu`` or ``cuda:N``.

    Raises:
        UnknownNameError: not ``cpu``, ``cuda`` or ``cuda:N`` (``cpu:N`` is refused too: torch
            runs one CPU device).
    """
    match = DEVICE_PATTERN.match(str(text).strip().lower())
    if not match or (match.group(1) == "cpu" and match.group(2) is not None):
        raise UnknownNameError(f"unknown device {text!r} (known: {DEVICES_HELP})")
    kind, index = match.group(1), match.group(2)
    return "cpu" if kind == "cpu" else f"cuda:{int(index or 0)}"


def require_device(text: str) -> torch.device:
    """``text`` as a :class:`torch.device` this process can run on.

    Raises:
        UnknownNameError: a misspelt device.
        DeviceUnavailableError: CUDA asked for where this torch is a CPU build, no GPU is
            visible, or the index is past the visible GPUs.
    """
    import torch

    name = device_name(text)
    if name == "cpu":
        return torch.device("cpu")
    if torch.version.cuda is None:
        raise DeviceUnavailableError(
            f"--device {text}: this torch ({torch.__version__}) is a CPU build without CUDA; "
            f"install a CUDA build of torch to run on a GPU")
    if not torch.cuda.is_available():
        raise DeviceUnavailableError(
            f"--device {text}: torch {torch.__version__} (CUDA {torch.version.cuda}) sees no "
            f"GPU (driver missing, or CUDA_VISIBLE_DEVICES hides them)")
    count = torch.cuda.device_count()
    index = int(name.split(":")[1])
    if index >= count:
        raise DeviceUnavailableError(f"--device {text}: only {count} GPU"
                                     f"{'s' if count != 1 else ''} visible (cuda:0 to "
                                     f"cuda:{count - 1})")
    return torch.device(name)


class PassTimer:
    """Seconds one call takes on ``device``: between two CUDA events on the current stream,
    then a synchronisation on the second, on a GPU; the host clock on the CPU (whose work is
    done when the call returns).

    Every call also keeps, in :attr:`walls` and :attr:`dispatches`, the host's wall clock from
    just before the call to the end of the synchronisation, and the host's time until the call
    returned (its dispatch: on a GPU the launches, on the CPU the whole pass);
    :meth:`reset` empties both (before the timed passes, after a warm-up)."""

    def __init__(self, device: torch.device | str = "cpu") -> None:
        import torch

        self.device = torch.device(device)
        self.kind = "cuda events" if self.device.type == "cuda" else "host clock"
        self.walls: list[float] = []
        self.dispatches: list[float] = []
        if self.device.type == "cuda":
            self._start = torch.cuda.Event(enable_timing=True)
            self._end = torch.cuda.Event(enable_timing=True)

    def reset(self) -> None:
        self.walls.clear()
        self.dispatches.clear()

    def __call__(self, call: Callable[[], object]) -> float:
        if self.device.type != "cuda":
            t0 = time.perf_counter()
            call()
            seconds = time.perf_counter() - t0
            self.walls.append(seconds)
            self.dispatches.append(seconds)
            return seconds
        t0 = time.perf_counter()
        self._start.record()
        call()
        dispatched = time.perf_counter()
        self._end.record()
        self._end.synchronize()
        self.walls.append(time.perf_counter() - t0)
        self.dispatches.append(dispatched - t0)
        return float(self._start.elapsed_time(self._end)) / 1e3


@dataclass(frozen=True)
class Settled:
    """What :func:`settle` did: ``passes`` run, ``seconds`` spent, whether the speed
    ``settled`` (False: stopped at the time limit still drifting) and the last window's median
    pass (s)."""

    passes: int
    seconds: float
    settled: bool
    median_s: float

    def as_dict(self) -> dict[str, Any]:
        return {"passes": self.passes, "seconds": self.seconds, "settled": self.settled,
                "median_ms": self.median_s * 1e3}


def settle(call: Callable[[], object], timer: Callable[[Callable[[], object]], float], *,
           window: int = 10, tolerance: float = 0.02, min_s: float = 1.0, max_s: float = 30.0,
           clock: Callable[[], float] = time.perf_counter) -> Settled:
    """Run ``call`` (timed by ``timer``) in windows of ``window`` passes until a window's
    median is within ``tolerance`` of the one before and at least ``min_s`` has passed, or
    until ``max_s``.

    Raises:
        ValueError: a window under 2 passes, a negative tolerance or ``max_s < min_s``.
    """
    if window < 2 or tolerance < 0 or max_s < min_s:
        raise ValueError(f"need window >= 2, tolerance >= 0 and max_s >= min_s (got {window}, "
                         f"{tolerance}, {min_s}, {max_s})")
    start = clock()
    previous: float | None = None
    passes = 0
    while True:
        median = statistics.median(timer(call) for _ in range(window))
        passes += window
        elapsed = clock() - start
        steady = previous is not None and abs(median - previous) <= tolerance * previous
        if (steady and elapsed >= min_s) or elapsed >= max_s:
            return Settled(passes, elapsed, bool(steady), median)
        previous = median
