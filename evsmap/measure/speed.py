"""Inference speed of a network (the paper's "FPS") on the CPU or a GPU, with an fp32 matmul
roofline of the same device.

On a GPU (``device="cuda[:N]"``) each pass is timed between CUDA events and synchronised
(:class:`evsmap.devices.PassTimer`), the device is warmed up until its speed settles
(:func:`evsmap.devices.settle`) instead of a fixed count of passes, cuDNN's autotuner is on,
and the record carries the GPU's facts (:func:`evsmap.environment.collect_gpu`), read again
after the timed passes so the clocks are those under load.

What runs a pass is a :class:`~evsmap.measure.speed_backends.Backend` object (torch eager,
compiled, a CUDA graph, ONNX Runtime on a provider: :mod:`evsmap.measure.speed_backends`); when
timing stops is a policy (:mod:`evsmap.measure.timing_policy`): until the median is precise
enough, or a fixed count of passes."""

from __future__ import annotations

import contextlib
import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
import torch

from evsmap.devices import PassTimer, Settled, require_device, settle
from evsmap.environment import LIBRARIES, collect_environment, collect_gpu
from evsmap.errors import UnknownNameError
from evsmap.measure.contention import Probe, contention, describe
from evsmap.measure.pass_timing import DeviceBusy, device_busy, pass_timing
from evsmap.measure.speed_backends import BACKENDS, Backend, PreparedPass, TorchEager
from evsmap.measure.timing_policy import (
    RoundsPolicy,
    SpeedPolicy,
    TimedPasses,
    TimingPolicy,
    median_ci,
    relative_half_width,
    time_until_precise,
)
from evsmap.models.module_utils import as_inputs, image_size

ROOFLINE_SIZE = 4096


@dataclass(frozen=True)
class SpeedRecord:
    """Timing of ``runs`` single forward passes (batch as given, usually 1).

    Attributes:
        backend: ``"torch"`` (eager, ``inference_mode``), ``"torch-compile"`` (``torch.compile``,
            TorchInductor, in ``compile_mode``), ``"torch-cuda-graph"`` (the eager pass captured
            once as a CUDA graph and replayed; a GPU only) or ``"onnxruntime"`` (all graph
            optimisations, on ``provider``).
        height, width: input image size.
        runs, warmup: timed forward passes, and untimed ones before them.
        threads: intra-op threads used (torch's after setting; onnxruntime's is set the same).
        ms_median, ms_iqr: median latency and its inter-quartile range (q75 - q25), ms.
        fps_median: ``1000 / ms_median``.
        fps_iqr: frames per second at the 25th latency percentile minus those at the 75th.
        times_ms: every timed forward pass, in order, ms.
        macs: multiply-accumulates of one forward pass (fvcore's total).
        roofline_gmacs: fp32 matmul throughput measured in the same call, G MAC/s.
        achieved_gmacs: ``macs`` per median forward pass, G MAC/s.
        roofline_fraction: ``achieved_gmacs / roofline_gmacs``.
        versions: python's and :data:`evsmap.environment.LIBRARIES`' versions.
        cpu: CPU model name.
        instruction_set: the vector instruction set the kernels ran with
            (:func:`evsmap.environment.instruction_set`).
        rounds: rounds of ``runs`` passes timed (more than one when repeating until stable).
        rel_iqr: ``ms_iqr / ms_median`` of the kept round.
        stable: the kept round met the requested ``stable_rel_iqr`` (None: none requested).
        contention: the machine around the kept round (:func:`evsmap.measure.contention.
            contention`: load, calibration slowdown against the run's best, ``contended``).
        calibration_gmacs: the calibration matmul's throughput around the kept round (the
            geometric mean of the probes just before and just after it): how fast the machine
            ran while this figure was taken. Two speeds each divided by their own calibration
            compare without the drift of a shared machine between them
            (:func:`calibrated_ratio`).
        ci_ms: the median's 95 % confidence interval (low, high), ms (percentile bootstrap,
            :func:`~evsmap.measure.timing_policy.median_ci`; under a policy, its interval).
        rel_ci: the precision reached: the interval's half-width over the median.
        stopped: why timing stopped (``"precision"``, ``"budget"``, ``"max_runs"``).
        timed_s: seconds spent on the timed passes.
        policy: the timing rule followed.
        session_s: seconds ONNX Runtime took to load and optimise the graph for this size
            (onnxruntime only; not cached across runs: it is a second or two even for the
            largest network here).
        device: ``cpu`` or ``cuda:N`` (:mod:`evsmap.devices`).
        timer: how a pass was timed: ``host clock`` or ``cuda events``.
        autocast: torch's mixed precision the passes ran under (``fp16``, ``bf16``), or None.
        provider: the ONNX Runtime execution provider the session ran with (onnxruntime only).
        compile_s: seconds of the first call of a ``torch-compile`` module (the compilation).
        settle: on a GPU, the warm-up until the speed settled (:class:`evsmap.devices.
            Settled`'s fields).
        gpu: the GPU's facts after the timed passes (:func:`evsmap.environment.collect_gpu`;
            empty on the CPU).
        compile_mode: ``torch.compile``'s mode (torch-compile only; :data:`COMPILE_MODES`).
        channels_last: the module and its 4-D inputs in channels-last memory format.
        timing: how each pass was timed (:class:`evsmap.measure.pass_timing.PassTiming`: host
            threads, pinned CPUs, stream, synchronisation, clock, settle).
        wall_ms_median: the host's wall clock per pass to the end of its synchronisation,
            median, ms (equals ``ms_median`` on the CPU; a GPU's events leave out the host's
            wait).
        dispatch_ms: the host's time until a pass's call returned, median, ms: on a GPU its
            launches (the kernels still run after), on the CPU the whole pass.
        busy: where the pass's time goes (:class:`evsmap.measure.pass_timing.DeviceBusy`:
            kernel time, device-busy share, ``bound``: launch, device or host).
    """

    backend: str
    height: int
    width: int
    runs: int
    warmup: int
    threads: int
    ms_median: float
    ms_iqr: float
    fps_median: float
    fps_iqr: float
    times_ms: list[float]
    macs: int
    roofline_gmacs: float
    achieved_gmacs: float
    roofline_fraction: float
    versions: dict[str, str] = field(default_factory=dict)
    cpu: str = ""
    instruction_set: str = ""
    rounds: int = 1
    rel_iqr: float = 0.0
    stable: bool | None = None
    contention: dict[str, Any] = field(default_factory=dict)
    calibration_gmacs: float | None = None
    ci_ms: list[float] | None = None
    rel_ci: float | None = None
    stopped: str | None = None
    timed_s: float | None = None
    policy: dict[str, Any] | None = None
    session_s: float | None = None
    device: str = "cpu"
    timer: str = "host clock"
    autocast: str | None = None
    provider: str | None = None
    compile_s: float | None = None
    settle: dict[str, Any] | None = None
    gpu: dict[str, Any] = field(default_factory=dict)
    compile_mode: str | None = None
    channels_last: bool = False
    timing: dict[str, Any] = field(default_factory=dict)
    wall_ms_median: float | None = None
    dispatch_ms: float | None = None
    busy: dict[str, Any] = field(default_factory=dict)

    @property
    def bound(self) -> str | None:
        """``launch``, ``device`` or ``host`` (:mod:`evsmap.measure.pass_timing`), or None."""
        return self.busy.get("bound")

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)

    @property
    def flag(self) -> str | None:
        """Why this figure should not be trusted as is, or None: a round that never met the
        stability threshold, or a machine busy with other work."""
        reasons = []
        if self.stable is False:
            reasons.append(f"unstable: IQR/median {self.rel_iqr:.2f} after {self.rounds} "
                           f"rounds of {self.runs}")
        if self.contention.get("contended"):
            reasons.append(describe(self.contention))
        return "; ".join(reasons) or None


def roofline_gmacs(size: int = ROOFLINE_SIZE, *, repeats: int = 3, warmup: int = 1,
                   backend: str = "torch", device: str = "cpu") -> float:
    """fp32 matmul throughput of this machine, G MAC/s, with the given backend.

    Times the product of two ``size`` x ``size`` float32 matrices (``size**3`` MACs):
    ``warmup`` untimed products, then the median of ``repeats`` timed ones. ``"torch"`` uses
    ``torch.matmul`` with torch's current thread count, on ``device`` (a GPU's products timed
    between CUDA events, with torch's TF32 setting, which the GPU record states);
    ``"onnxruntime"`` runs a one-node ``MatMul`` graph on the CPU execution provider with the
    same number of intra-op threads, so a network is compared with the best its own runtime
    does on dense fp32 arithmetic.
    """
    if size < 1 or repeats < 1 or warmup < 0:
        raise ValueError("size and repeats must be >= 1, warmup >= 0")
    if backend not in BACKENDS:
        raise UnknownNameError(f"unknown backend {backend!r} (known: {', '.join(BACKENDS)})")
    gen = torch.Generator().manual_seed(0)
    a = torch.rand(size, size, generator=gen, dtype=torch.float32)
    b = torch.rand(size, size, generator=gen, dtype=torch.float32)
    timer = PassTimer("cpu")
    if backend != "onnxruntime":
        dev = require_device(device)
        a, b, timer = a.to(dev), b.to(dev), PassTimer(dev)
        out = torch.empty(size, size, dtype=torch.float32, device=dev)

        def product() -> None:
            torch.matmul(a, b, out=out)
    else:
        session = _matmul_session(size, torch.get_num_threads())
        feed = {"a": a.numpy(), "b": b.numpy()}

        def product() -> None:
            session.run(None, feed)
    with torch.inference_mode():
        times = _time_calls(product, repeats, warmup, timer)
    return float(size) ** 3 / float(np.median(times)) / 1e9


def _matmul_session(size: int, threads: int) -> Any:
    import onnx
    import onnxruntime as ort
    from onnx import TensorProto, helper

    def tensor(name: str) -> onnx.ValueInfoProto:
        return helper.make_tensor_value_info(name, TensorProto.FLOAT, [size, size])

    graph = helper.make_graph([helper.make_node("MatMul", ["a", "b"], ["y"])], "roofline",
                              [tensor("a"), tensor("b")], [tensor("y")])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    options = ort.SessionOptions()
    options.intra_op_num_threads = threads
    options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    return ort.InferenceSession(model.SerializeToString(), options,
                                providers=["CPUExecutionProvider"])


def measure_speed(
    module: torch.nn.Module,
    inputs: torch.Tensor | Sequence[torch.Tensor],
    *,
    backend: Backend | None = None,
    policy: SpeedPolicy | None = None,
    device: str = "cpu",
    threads: int | None = None,
    macs: int | None = None,
    roofline: float | None = None,
    roofline_size: int = ROOFLINE_SIZE,
    calibration_log: Any = None,
    pin: bool = True,
) -> SpeedRecord:
    """Time forward passes of ``module(*inputs)`` on ``backend`` under ``policy``.

    Args:
        backend: how a pass runs (:mod:`evsmap.measure.speed_backends`: torch eager, compiled,
            a CUDA graph, ONNX Runtime on a provider; default :class:`~evsmap.measure.
            speed_backends.TorchEager`, fp32).
        policy: when timing stops: a :class:`~evsmap.measure.timing_policy.TimingPolicy`
            (pass by pass until the median is precise enough or the budget is spent) or a
            :class:`~evsmap.measure.timing_policy.RoundsPolicy` (rounds of a fixed count of
            passes; the default, 20 passes after 3 untimed ones).
        device: ``cpu`` or ``cuda[:N]`` (:func:`evsmap.devices.require_device`); on a GPU the
            module is copied there, the warm-up runs until the speed settles (then the
            policy's warm-up) and cuDNN's autotuner is on.
        threads: host intra-op threads for torch and onnxruntime (default: one on a GPU,
            torch's current count on the CPU: :func:`~evsmap.measure.pass_timing.pass_timing`);
            torch's count is restored on return.
        macs: MACs of one forward pass; measured with
            :func:`~evsmap.measure.complexity.measure_complexity` when not given.
        roofline: the fp32 matmul roofline already measured for this machine and thread count
            (G MAC/s); else measured in this call with torch at ``roofline_size`` (one
            machine-level ceiling for every backend; ONNX Runtime's own MatMul reaches about
            the same or less here).
        calibration_log: a :class:`~evsmap.measure.contention.CalibrationLog` holding the
            run's best calibration (default: this call's own).
        pin: pin the process to the lowest ``threads`` CPUs while timing (the gate's rule;
            :class:`~evsmap.measure.pass_timing.PassTiming`).

    Each pass is timed as :mod:`evsmap.measure.pass_timing` defines (the gate times its network
    workloads the same way): the host clock on the CPU, CUDA events on a GPU with the wall clock
    and the host's dispatch time beside; on a GPU the device-busy share of a pass is measured
    after the timed passes (``busy``).

    Raises:
        UnknownNameError: ``device`` unknown.
        DeviceUnavailableError: the device or provider is not on this machine, or a GPU-only
            backend on the CPU.
        InvalidDataError: a backend's settings that do not go with the device (a provider of
            another device, mixed precision on ONNX Runtime's CPU or CUDA provider).
        OnnxExportError: the onnxruntime backend could not export the module.
    """
    backend = backend or TorchEager()
    policy = policy or RoundsPolicy()
    if threads is not None and threads < 1:
        raise ValueError(f"threads must be >= 1, got {threads}")
    require_device(device)  # one line, before anything is built, where this machine has none
    timing = pass_timing(device, threads, pin=pin)
    inputs = as_inputs(inputs)
    macs = _measured_macs(module, inputs) if macs is None else macs
    timer = PassTimer(timing.device)
    with timing.applied():
        first = Probe.take()  # the machine before the first timed pass
        prepared = backend.prepare(module, inputs, timing.device, timer)
        settled = _settle(prepared.call, timer, prepared.context) if timing.settle else None
        timer.reset()
        timed = _time_passes(prepared, policy, first, timer)
        busy = _busy(prepared, timed, timing.device)
        if roofline is None:
            roofline = roofline_gmacs(roofline_size, device=timing.device)
    record = _speed_record(timed, size=image_size(inputs), threads=timing.host_threads,
                           macs=int(macs), roofline=roofline, policy=policy,
                           calibration_log=calibration_log, backend=backend.record_fields())
    return dataclasses.replace(
        record, device=timing.device, timer=timer.kind, provider=prepared.provider,
        compile_s=prepared.compile_s, session_s=prepared.session_s,
        settle=settled.as_dict() if settled else None, gpu=collect_gpu(torch.device(timing.device)),
        compile_mode=prepared.compile_mode, timing=timing.as_dict(),
        wall_ms_median=_median_ms(timer.walls), dispatch_ms=_median_ms(timer.dispatches),
        busy=busy.as_dict())


def _measured_macs(module: torch.nn.Module, inputs: tuple[torch.Tensor, ...]) -> int:
    from evsmap.measure.complexity import measure_complexity

    return int(measure_complexity(module, inputs).flops)


def _median_ms(seconds: list[float]) -> float | None:
    return float(np.median(seconds)) * 1e3 if seconds else None


def _busy(prepared: PreparedPass, timed: _Timed, device: str) -> DeviceBusy:
    """The device-busy share of the timed pass (the profiler's passes run in its context)."""
    with prepared.context():
        return device_busy(prepared.call, float(np.median(timed.times)), device)


def _settle(call: Callable[[], object], timer: PassTimer,
            context: Callable[[], contextlib.AbstractContextManager[None]]) -> Settled:
    with context():
        return settle(call, timer)


@dataclass
class _Timed:
    """What timing the forward passes gave: the kept ``times`` (s), the ``rounds`` timed, the
    kept round's ``rel_iqr``, the machine ``probes`` around it and, under a timing policy, the
    ``passes``."""

    times: list[float]
    rounds: int
    rel_iqr: float
    probes: tuple[Any, Any]
    warmup: int
    passes: TimedPasses | None = None


def _time_precisely(call: Callable[[], object], policy: TimingPolicy, first: Probe,
                    context: Callable[[], contextlib.AbstractContextManager[None]],
                    timer: PassTimer) -> _Timed:
    """Time pass by pass (in ``context``, each by ``timer``) until ``policy`` is met;
    ``first`` is the machine probe taken before, one more is taken after."""
    with context():
        passes = time_until_precise(call, policy, pass_timer=timer)
    return _Timed(passes.times_s, 1, _rel_iqr(passes.times_s), (first, Probe.take()),
                  passes.warmup_runs, passes)


def _time_passes(prepared: PreparedPass, policy: SpeedPolicy, first: Probe,
                 timer: PassTimer) -> _Timed:
    """The passes of ``prepared`` timed under ``policy`` (``first``: the machine probe taken
    before them)."""
    if isinstance(policy, TimingPolicy):
        return _time_precisely(prepared.call, policy, first, prepared.context, timer)
    return _time_in_rounds(prepared.call, policy, first, prepared.context, timer)


def _time_in_rounds(call: Callable[[], object], policy: RoundsPolicy, first: Probe,
                    context: Callable[[], contextlib.AbstractContextManager[None]],
                    timer: PassTimer) -> _Timed:
    """Rounds of ``policy.runs`` passes (each in ``context``; ``policy.warmup`` untimed ones
    before the first) until one's IQR / median is at most ``policy.stable_rel_iqr``, at most
    ``policy.max_rounds``; the stable round, else the steadiest, with the machine probes just
    before and after it (``first`` the one taken before the first round)."""
    probes = [first]  # one before every round and one after the last
    kept: list[float] = []
    kept_rel, kept_round = float("inf"), 0
    for r in range(policy.max_rounds):
        with context():
            times = _time_calls(call, policy.runs, policy.warmup if r == 0 else 0, timer)
        probes.append(Probe.take())
        rel = _rel_iqr(times)
        stable = policy.stable_rel_iqr is not None and rel <= policy.stable_rel_iqr
        if rel < kept_rel or stable:
            kept, kept_rel, kept_round = times, rel, r
        if stable:
            break
    return _Timed(kept, len(probes) - 1, kept_rel, (probes[kept_round], probes[kept_round + 1]),
                  policy.warmup)


def _speed_record(timed: _Timed, *, size: tuple[int, int], threads: int, macs: int,
                  roofline: float, policy: SpeedPolicy, calibration_log: Any,
                  backend: dict[str, Any]) -> SpeedRecord:
    """The record of ``timed``: latency and speed percentiles, the roofline fraction, the
    machine (:func:`~evsmap.environment.collect_environment`) and its contention; ``backend``
    the backend's fields (:meth:`~evsmap.measure.speed_backends.Backend.record_fields`)."""
    stable_rel_iqr = policy.stable_rel_iqr if isinstance(policy, RoundsPolicy) else None
    times_ms = [t * 1000.0 for t in timed.times]
    q25, median, q75 = (float(v) for v in np.percentile(times_ms, [25, 50, 75]))
    achieved = macs / (median / 1000.0) / 1e9
    before, after = timed.probes
    env = collect_environment(threads)
    return SpeedRecord(
        **backend, height=size[0], width=size[1], runs=len(times_ms),
        warmup=timed.warmup, threads=threads, ms_median=median, ms_iqr=q75 - q25,
        fps_median=1000.0 / median, fps_iqr=1000.0 / q25 - 1000.0 / q75,
        times_ms=times_ms, macs=macs, roofline_gmacs=roofline, achieved_gmacs=achieved,
        roofline_fraction=achieved / roofline,
        versions={"python": env["python"], **{k: env["versions"][k] for k in LIBRARIES}},
        cpu=env["cpu"], instruction_set=env["instruction_set"],
        rounds=timed.rounds, rel_iqr=(q75 - q25) / median,
        stable=None if stable_rel_iqr is None else bool(timed.rel_iqr <= stable_rel_iqr),
        contention=contention(before, after, calibration_log),
        calibration_gmacs=math.sqrt(before.calibration_gmacs * after.calibration_gmacs),
        **_precision_fields(timed),
    )


def _precision_fields(timed: _Timed) -> dict[str, Any]:
    """The median's confidence interval and precision: the timing policy's, or, for passes
    timed in rounds, the same percentile-bootstrap interval of the kept round (so every record
    states how far its median can be trusted)."""
    passes = timed.passes
    if passes is None:
        median, low, high = median_ci(timed.times)
        return {"ci_ms": [low * 1000.0, high * 1000.0],
                "rel_ci": relative_half_width(median, low, high)}
    return {"ci_ms": [passes.ci_s[0] * 1000.0, passes.ci_s[1] * 1000.0],
            "rel_ci": passes.rel_ci, "stopped": passes.stopped, "timed_s": passes.timed_s,
            "policy": dict(passes.policy)}


def calibrated_ratio(fps_a: float, cal_a: float | None, fps_b: float,
                     cal_b: float | None) -> float:
    """``fps_a / fps_b`` with each speed first divided by the calibration taken around it
    (:attr:`SpeedRecord.calibration_gmacs`), so a machine that ran slower while one of the two
    was timed (another VM on the host, a frequency step) does not move the ratio; the plain
    ratio when either calibration is missing."""
    if cal_a and cal_b and cal_a > 0 and cal_b > 0:
        return (fps_a / cal_a) / (fps_b / cal_b)
    return fps_a / fps_b


def _rel_iqr(times: list[float]) -> float:
    q25, median, q75 = np.percentile(times, [25, 50, 75])
    return float((q75 - q25) / median) if median > 0 else float("inf")


def _time_calls(forward: Callable[[], object], runs: int, warmup: int,
                timer: Callable[[Callable[[], object]], float] | None = None) -> list[float]:
    """``warmup`` untimed calls, then ``runs`` timed by ``timer`` (the host clock by
    default)."""
    timer = timer or PassTimer("cpu")
    for _ in range(warmup):
        forward()
    return [timer(forward) for _ in range(runs)]
