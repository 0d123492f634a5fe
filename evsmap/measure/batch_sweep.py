"""Throughput beside latency: each network timed at several batch sizes under one timing rule.

The paper's FPS could be a latency figure (one image a pass) or a throughput one (a batch a
pass, divided by the batch); a launch-bound GPU pass gets much faster per image as the batch
grows, so the two can differ several-fold. :func:`batch_sweep` times every network at every
batch (default :data:`DEFAULT_BATCHES`) with the same :class:`~evsmap.measure.timing_policy.
TimingPolicy`, the networks alternating at each batch so drift of the machine falls on all of
them alike, and gives per point the pass time, the FPS per image (``batch / pass time``) and
the ratio of that FPS to the reference network's at the same batch (ESANet-R34-NBt1D, Table I's
yardstick). A batch that does not fit in memory (CUDA's out-of-memory error, a ``MemoryError``)
is recorded as such, and the network's larger batches with it, instead of ending the sweep.

Records only; the command line formats them (``evsmap speed --batch``).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import torch

from evsmap.devices import require_device
from evsmap.measure.speed import SpeedRecord, measure_speed
from evsmap.measure.timing_policy import TimingPolicy
from evsmap.models.module_utils import as_inputs

DEFAULT_BATCHES = (1, 2, 4, 8, 16)
REFERENCE = "esanet-r34-nbt1d"
"""The network every other is compared with at each batch (Table I's ESANet-R34-NBt1D)."""

Measure = Callable[..., SpeedRecord]


@dataclass(frozen=True)
class SweepNetwork:
    """One network to sweep: its ``name``, the ``module`` and its batch-1 ``inputs``
    (``segmenter.example_inputs(h, w)``), and the MACs of one batch-1 pass when known."""

    name: str
    module: torch.nn.Module
    inputs: tuple[torch.Tensor, ...]
    macs: int | None = None


@dataclass(frozen=True)
class BatchPoint:
    """One network at one batch size.

    Attributes:
        network, batch: what was timed.
        ms_median: the median pass over the whole batch, ms (None: not timed).
        fps_per_image: ``batch * 1000 / ms_median``: images a second.
        ratio_to_reference: ``fps_per_image`` over the reference network's at this batch
            (None where either was not timed, or there is no reference).
        refused: why the point was not timed, in one line (``"out of memory: ..."``), or None.
        speed: the full speed record of the point (:class:`~evsmap.measure.speed.SpeedRecord`).
    """

    network: str
    batch: int
    ms_median: float | None = None
    fps_per_image: float | None = None
    ratio_to_reference: float | None = None
    refused: str | None = None
    speed: SpeedRecord | None = None

    @property
    def out_of_memory(self) -> bool:
        return self.refused is not None and self.refused.startswith("out of memory")

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True)
class BatchSweep:
    """Every point of a sweep, in the order timed, with what they share."""

    batches: tuple[int, ...]
    reference: str | None
    device: str
    policy: dict[str, Any]
    points: list[BatchPoint] = field(default_factory=list)

    def point(self, network: str, batch: int) -> BatchPoint:
        for p in self.points:
            if (p.network, p.batch) == (network, batch):
                return p
        raise KeyError(f"no point for {network} at batch {batch}")

    @property
    def networks(self) -> list[str]:
        return list(dict.fromkeys(p.network for p in self.points))

    def as_dict(self) -> dict[str, Any]:
        return {"batches": list(self.batches), "reference": self.reference,
                "device": self.device, "policy": self.policy,
                "points": [p.as_dict() for p in self.points]}


def check_batches(batches: Sequence[int]) -> tuple[int, ...]:
    """``batches`` as a tuple of distinct sizes in the order given.

    Raises:
        ValueError: none given, a size under 1 or one given twice.
    """
    sizes = tuple(int(b) for b in batches)
    if not sizes or min(sizes) < 1 or len(set(sizes)) != len(sizes):
        raise ValueError(f"batch sizes must be distinct integers >= 1, got {list(batches)}")
    return sizes


def repeat_batch(inputs: Sequence[torch.Tensor], batch: int) -> tuple[torch.Tensor, ...]:
    """The batch-1 ``inputs`` repeated ``batch`` times along the first dimension (the same
    image ``batch`` times, contiguous, so every image of the batch costs what the first does)."""
    tensors = as_inputs(inputs)
    if any(t.shape[0] != 1 for t in tensors):
        shapes = [tuple(t.shape) for t in tensors]
        raise ValueError(f"inputs must have batch 1, got shapes {shapes}")
    return tuple(t.expand(batch, *t.shape[1:]).contiguous() for t in tensors)


def batch_sweep(networks: Sequence[SweepNetwork], *, batches: Sequence[int] = DEFAULT_BATCHES,
                reference: str | None = REFERENCE, policy: TimingPolicy | None = None,
                device: str = "cpu", measure: Measure = measure_speed,
                **speed_options: Any) -> BatchSweep:
    """Time every network at every batch size (module docstring).

    Args:
        networks: the networks, each with batch-1 inputs.
        batches: the batch sizes, timed in this order.
        reference: the name (among ``networks``) whose FPS per image the others are divided
            by at each batch; None: no ratios.
        policy: the timing rule every point follows (default :class:`TimingPolicy`'s).
        device: ``cpu`` or ``cuda[:N]``.
        measure: the timing function (:func:`~evsmap.measure.speed.measure_speed`).
        speed_options: more keyword arguments of ``measure`` (``backend``, a
            :class:`~evsmap.measure.speed_backends.Backend`; ``threads``, ``roofline``, ...),
            the same for every point.

    Raises:
        DeviceUnavailableError: the device is not on this machine.
        ValueError: bad batch sizes, no network, a name given twice, or a ``reference`` that
            is not among the networks.
    """
    require_device(device)  # before any work: a device that is not here is one line
    sizes = check_batches(batches)
    names = [n.name for n in networks]
    if not names or len(set(names)) != len(names):
        raise ValueError(f"need distinct network names, got {names}")
    if reference is not None and reference not in names:
        raise ValueError(f"reference {reference!r} is not among the networks {names}")
    policy = policy or TimingPolicy()
    if "roofline" not in speed_options:
        from evsmap.measure.speed import roofline_gmacs

        speed_options["roofline"] = roofline_gmacs(device=device)  # once for the sweep
    refused: dict[str, str] = {}  # a network's first out-of-memory batch
    points = []
    for batch in sizes:
        for net in networks:  # alternating: every network at this batch, then the next batch
            if net.name in refused:
                points.append(BatchPoint(net.name, batch, refused=refused[net.name]))
                continue
            point = _time_point(net, batch, policy, device, measure, speed_options)
            if point.out_of_memory:
                refused[net.name] = f"out of memory at batch {batch} (larger not tried)"
            points.append(point)
    return BatchSweep(sizes, reference, device, policy.as_dict(), with_ratios(points, reference))


def _time_point(net: SweepNetwork, batch: int, policy: TimingPolicy, device: str,
                measure: Measure, options: dict[str, Any]) -> BatchPoint:
    macs = net.macs * batch if net.macs is not None else None
    try:
        record = measure(net.module, repeat_batch(net.inputs, batch), policy=policy,
                         device=device, macs=macs, **options)
    except Exception as exc:  # out of memory only; anything else is a real failure
        if not is_out_of_memory(exc):
            raise
        free_device_memory(device)
        return BatchPoint(net.name, batch, refused=f"out of memory: {first_line(exc)}")
    return BatchPoint(net.name, batch, ms_median=record.ms_median,
                      fps_per_image=batch * 1000.0 / record.ms_median, speed=record)


def with_ratios(points: Sequence[BatchPoint], reference: str | None) -> list[BatchPoint]:
    """``points`` with ``ratio_to_reference`` set: each timed point's FPS per image over the
    reference's at the same batch (None where the reference's point was not timed)."""
    ref = {p.batch: p.fps_per_image for p in points
           if p.network == reference and p.fps_per_image is not None}
    out = []
    for p in points:
        base = ref.get(p.batch)
        ratio = p.fps_per_image / base if p.fps_per_image is not None and base else None
        out.append(replace(p, ratio_to_reference=ratio))
    return out


def is_out_of_memory(exc: BaseException) -> bool:
    """Whether ``exc`` says the device ran out of memory: torch's ``OutOfMemoryError`` (CUDA,
    and the CPU allocator's in recent torch), a ``MemoryError``, or the CPU allocator's
    ``RuntimeError`` of older torch."""
    if isinstance(exc, MemoryError | torch.OutOfMemoryError):
        return True
    text = str(exc).lower()
    return isinstance(exc, RuntimeError) and ("out of memory" in text
                                              or "can't allocate memory" in text)


def first_line(exc: BaseException) -> str:
    lines = str(exc).strip().splitlines()
    return lines[0] if lines else type(exc).__name__


def free_device_memory(device: str) -> None:
    if device.startswith("cuda") and torch.cuda.is_available():
        torch.cuda.empty_cache()
