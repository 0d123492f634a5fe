"""Inference speed of a network (the paper's "FPS") on the CPU or a GPU, with an fp32 matmul
roofline of the same device.

On a GPU (``device="cuda[:N]"``) each pass is timed between CUDA events and synchronised
(:class:`evsmap.devices.PassTimer`), the device is warmed up until its speed settles
(:func:`evsmap.devices.settle`) instead of a fixed count of passes, cuDNN's autotuner is on,
and the record carries the GPU's facts (:func:`evsmap.environment.collect_gpu`), read again
after the timed passes so the clocks are those under load."""

from __future__ import annotations

import contextlib
import copy
import dataclasses
import functools
import math
import os
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
import torch

from evsmap.devices import PassTimer, Settled, require_device, settle
from evsmap.environment import LIBRARIES, collect_environment, collect_gpu
from evsmap.errors import InvalidDataError, UnknownNameError
from evsmap.measure.contention import Probe, contention, describe
from evsmap.measure.pass_timing import DeviceBusy, device_busy, pass_timing
from evsmap.measure.timing_policy import (
    TimedPasses,
    TimingPolicy,
    median_ci,
    relative_half_width,
    time_until_precise,
)
from evsmap.models.module_utils import as_inputs, eval_mode, image_size

BACKENDS = ("onnxruntime", "torch", "torch-compile", "torch-cuda-graph")
GPU_BACKENDS = ("torch-cuda-graph",)
"""Backends that only run on a GPU."""
COMPILE_MODES = ("default", "reduce-overhead", "max-autotune")
"""``torch.compile``'s modes (``reduce-overhead`` replays CUDA graphs on a GPU)."""
AUTOCASTS = ("fp16", "bf16")
"""``autocast`` values: torch's mixed precision (``torch.autocast``) at this dtype."""
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
    backend: str = "torch",
    runs: int = 20,
    warmup: int = 3,
    threads: int | None = None,
    macs: int | None = None,
    input_names: Sequence[str] | None = None,
    key: str | None = None,
    cache_dir: str | os.PathLike[str] | None = None,
    roofline_size: int = ROOFLINE_SIZE,
    max_rounds: int = 1,
    stable_rel_iqr: float | None = None,
    calibration_log: Any = None,
    onnx_path: str | os.PathLike[str] | None = None,
    policy: TimingPolicy | None = None,
    roofline: float | None = None,
    free_dimensions: dict[str, int] | None = None,
    device: str = "cpu",
    autocast: str | None = None,
    provider: str | None = None,
    compile_mode: str | None = None,
    channels_last: bool = False,
    pin: bool = True,
) -> SpeedRecord:
    """Time ``runs`` forward passes of ``module(*inputs)`` after ``warmup`` untimed ones.

    Args:
        backend: ``"torch"`` (eval mode, ``torch.inference_mode``) or ``"onnxruntime"`` (the
            module exported with :func:`~evsmap.models.onnx_export.cached_onnx`, run on the
            CPU execution provider with all graph optimisations, inputs as numpy arrays).
        threads: host intra-op threads for torch and onnxruntime (default: one on a GPU,
            torch's current count on the CPU: :func:`~evsmap.measure.pass_timing.pass_timing`);
            torch's count is restored on return.
        macs: MACs of one forward pass; measured with
            :func:`~evsmap.measure.complexity.measure_complexity` when not given.
        input_names: ONNX input names (default ``input0``, ``input1``, ...).
        key: name of the ONNX cache entry (default: the module's class name).
        cache_dir: ONNX cache folder (default
            :func:`~evsmap.models.onnx_export.default_cache_dir`).
        roofline_size: matrix size of the fp32 matmul roofline, measured in this call with
            torch and the same thread count for either backend (one machine-level ceiling;
            ONNX Runtime's own MatMul reaches about the same or less here).
        max_rounds, stable_rel_iqr: time rounds of ``runs`` passes until one has
            ``IQR / median <= stable_rel_iqr``, at most ``max_rounds``; the record keeps that
            round, else the steadiest one and ``stable=False``.
        calibration_log: a :class:`~evsmap.measure.contention.CalibrationLog` holding the
            run's best calibration (default: this call's own).
        onnx_path: with onnxruntime, time this ONNX file (e.g. the module's int8
            quantisation) instead of the module's cached fp32 export.
        policy: time pass by pass until the median is precise enough or the budget is spent
            (:func:`~evsmap.measure.timing_policy.time_until_precise`) instead of in rounds of
            ``runs`` (``runs``, ``warmup``, ``max_rounds`` and ``stable_rel_iqr`` then unused).
        roofline: the fp32 matmul roofline already measured for this machine and thread count
            (G MAC/s); measured in this call when None.
        free_dimensions: with ``onnx_path``, the graph's free dimensions pinned for this
            session (a size-free export timed at one size:
            :func:`~evsmap.models.speed_export.speed_export`).

        device: ``cpu`` or ``cuda[:N]`` (:func:`evsmap.devices.require_device`); on a GPU the
            module is copied there, the warm-up runs until the speed settles (then ``warmup``
            more passes) and cuDNN's autotuner is on.
        autocast: ``fp16`` or ``bf16``: the torch backends run under ``torch.autocast`` at
            that dtype; with the ``tensorrt`` provider, ``fp16`` builds fp16 engines.
        provider: ONNX Runtime's execution provider (:data:`evsmap.models.ort_providers.
            PROVIDERS`; default ``cpu`` on the CPU, ``cuda`` on a GPU).
        compile_mode: ``torch.compile``'s mode with backend ``torch-compile``
            (:data:`COMPILE_MODES`; default ``default``).
        channels_last: the module and its 4-D inputs in channels-last memory format (the
            torch backends).
        pin: pin the process to the lowest ``threads`` CPUs while timing (the gate's rule;
            :class:`~evsmap.measure.pass_timing.PassTiming`).

    Each pass is timed as :mod:`evsmap.measure.pass_timing` defines (the gate times its network
    workloads the same way): the host clock on the CPU, CUDA events on a GPU with the wall clock
    and the host's dispatch time beside; on a GPU the device-busy share of a pass is measured
    after the timed passes (``busy``).

    Raises:
        UnknownNameError: ``backend``, ``autocast``, ``provider`` or ``device`` unknown.
        DeviceUnavailableError: the device or provider is not on this machine.
        InvalidDataError: settings that do not go together (a provider of another device,
            mixed precision on ONNX Runtime's CPU or CUDA provider).
        OnnxExportError: the onnxruntime backend could not export the module.
    """
    _check_settings(backend, runs, warmup, threads, max_rounds)
    require_device(device)  # one line, before anything is built, where this machine has none
    timing = pass_timing(device, threads, pin=pin)
    inputs = as_inputs(inputs)
    if macs is None:
        from evsmap.measure.complexity import measure_complexity

        macs = measure_complexity(module, inputs).flops
    timer = PassTimer(timing.device)
    with timing.applied():
        first = Probe.take()  # the machine before the first timed pass
        prepared = prepare_pass(
            module, inputs, backend=backend, device=timing.device, autocast=autocast,
            provider=provider, compile_mode=compile_mode, channels_last=channels_last,
            input_names=input_names, key=key, cache_dir=cache_dir, onnx_path=onnx_path,
            free_dimensions=free_dimensions, timer=timer)
        settled = _settle(prepared.call, timer, prepared.context) if timing.settle else None
        timer.reset()
        timed = (_time_precisely(prepared.call, policy, first, prepared.context, timer)
                 if policy is not None
                 else _time_in_rounds(prepared.call, runs, warmup, max_rounds, stable_rel_iqr,
                                      first, prepared.context, timer))
        busy = _busy(prepared, timed, timing.device)
        if roofline is None:
            roofline = roofline_gmacs(roofline_size, device=timing.device)
    record = _speed_record(timed, backend=backend, size=image_size(inputs),
                           threads=timing.host_threads, macs=int(macs), roofline=roofline,
                           stable_rel_iqr=stable_rel_iqr, calibration_log=calibration_log,
                           session_s=prepared.session_s)
    return dataclasses.replace(
        record, device=timing.device, timer=timer.kind, autocast=autocast,
        provider=prepared.provider, compile_s=prepared.compile_s,
        settle=settled.as_dict() if settled else None, gpu=collect_gpu(torch.device(timing.device)),
        compile_mode=prepared.compile_mode, channels_last=channels_last,
        timing=timing.as_dict(), wall_ms_median=_median_ms(timer.walls),
        dispatch_ms=_median_ms(timer.dispatches), busy=busy.as_dict())


def _median_ms(seconds: list[float]) -> float | None:
    return float(np.median(seconds)) * 1e3 if seconds else None


def _busy(prepared: PreparedPass, timed: _Timed, device: str) -> DeviceBusy:
    """The device-busy share of the timed pass (the profiler's passes run in its context)."""
    with prepared.context():
        return device_busy(prepared.call, float(np.median(timed.times)), device)


@dataclass
class PreparedPass:
    """One forward pass ready to time: ``call`` runs it and returns its output (logits, or ONNX
    Runtime's arrays), ``context`` is what every call runs in (eval mode, inference mode,
    autocast, cuDNN's autotuner); ``compile_s`` the first call of a compiled module,
    ``session_s`` ONNX Runtime's session, ``provider`` the provider it runs with."""

    call: Callable[[], Any]
    context: Callable[[], contextlib.AbstractContextManager[None]]
    provider: str | None = None
    compile_mode: str | None = None
    compile_s: float | None = None
    session_s: float | None = None


def prepare_pass(module: torch.nn.Module, inputs: Sequence[torch.Tensor], *,
                 backend: str = "torch", device: str = "cpu", autocast: str | None = None,
                 provider: str | None = None, compile_mode: str | None = None,
                 channels_last: bool = False, input_names: Sequence[str] | None = None,
                 key: str | None = None, cache_dir: str | os.PathLike[str] | None = None,
                 onnx_path: str | os.PathLike[str] | None = None,
                 free_dimensions: dict[str, int] | None = None,
                 timer: PassTimer | None = None) -> PreparedPass:
    """``module(*inputs)`` on ``backend`` and ``device``, ready to time (:class:`PreparedPass`):
    the module copied to the device, compiled, captured or exported as the backend needs, its
    one-off cost (compilation, session) paid here and recorded.

    Raises:
        UnknownNameError: an unknown backend, autocast, compile mode or provider.
        DeviceUnavailableError: the device or provider is not on this machine, or a GPU-only
            backend (torch-cuda-graph) asked for on the CPU.
        InvalidDataError: settings that do not go together.
    """
    dev = require_device(device)
    provider = _check_device_settings(backend, dev, autocast, provider)
    compile_mode = _check_variant(backend, dev, compile_mode, channels_last)
    inputs = as_inputs(inputs)
    timer = timer or PassTimer(dev)
    if backend == "onnxruntime":
        t0 = time.perf_counter()
        run, used = _onnxruntime_forward(
            module, inputs, input_names, torch.get_num_threads(), key or type(module).__name__,
            cache_dir, onnx_path, free_dimensions, provider=provider, device=dev,
            fp16=autocast == "fp16")
        return PreparedPass(run, contextlib.nullcontext, provider=used,
                            session_s=time.perf_counter() - t0)
    model = _on_device(module, dev, channels_last)
    args = tuple(_placed(t, dev, channels_last) for t in inputs)
    context = functools.partial(_timing_context, model, backend, dev, autocast)
    if backend == "torch-cuda-graph":
        return PreparedPass(_captured(model, args, context), context)
    if backend == "torch":
        return PreparedPass(functools.partial(model, *args), context)
    compiled = functools.partial(torch.compile(model, mode=compile_mode), *args)
    with context():
        compile_s = timer(compiled)  # the first call compiles
    return PreparedPass(compiled, context, compile_mode=compile_mode, compile_s=compile_s)


def _check_device_settings(backend: str, device: torch.device, autocast: str | None,
                           provider: str | None) -> str | None:
    """The ONNX Runtime provider to use (None for the torch backends), after refusing what
    does not go together: an unknown autocast, a provider with a torch backend or of another
    device, mixed precision on ONNX Runtime other than TensorRT's fp16."""
    from evsmap.models.ort_providers import PROVIDERS, default_provider

    if autocast is not None and autocast not in AUTOCASTS:
        raise UnknownNameError(f"unknown autocast {autocast!r} (known: {', '.join(AUTOCASTS)})")
    if backend != "onnxruntime":
        if provider is not None:
            raise InvalidDataError(f"provider {provider!r} is ONNX Runtime's: it needs backend "
                                   f"onnxruntime (backend {backend!r} given)")
        return None
    provider = provider or default_provider(str(device))
    if provider not in PROVIDERS:
        raise UnknownNameError(f"unknown ONNX Runtime provider {provider!r} (known: "
                               f"{', '.join(PROVIDERS)})")
    if (provider == "cpu") != (device.type == "cpu"):
        raise InvalidDataError(f"provider {provider} does not run on device {device}: the cpu "
                               f"provider runs on the CPU, cuda and tensorrt on a GPU (pass "
                               f"the device: --device cpu or cuda)")
    if autocast is not None and (provider, autocast) != ("tensorrt", "fp16"):
        raise InvalidDataError(f"{autocast} on ONNX Runtime: only TensorRT builds fp16 engines "
                               f"(provider tensorrt); the {provider} provider runs the fp32 "
                               f"export (use backend torch or torch-compile for {autocast})")
    return provider


def _check_variant(backend: str, device: torch.device, compile_mode: str | None,
                   channels_last: bool) -> str | None:
    """The compile mode to use (None unless torch-compile), after refusing a GPU-only backend
    on the CPU, a mode without torch-compile, and channels-last on ONNX Runtime."""
    from evsmap.devices import DeviceUnavailableError

    if backend in GPU_BACKENDS and device.type != "cuda":
        raise DeviceUnavailableError(f"backend {backend} replays a captured CUDA graph: it needs "
                                     f"a GPU (--device cuda), not {device}")
    if compile_mode is not None and compile_mode not in COMPILE_MODES:
        raise UnknownNameError(f"unknown compile mode {compile_mode!r} (known: "
                               f"{', '.join(COMPILE_MODES)})")
    if compile_mode is not None and backend != "torch-compile":
        raise InvalidDataError(f"compile mode {compile_mode} is torch.compile's: it needs "
                               f"backend torch-compile (backend {backend!r} given)")
    if channels_last and backend == "onnxruntime":
        raise InvalidDataError("channels-last is a torch memory format: ONNX Runtime chooses "
                               "its own layouts (use backend torch, torch-compile or "
                               "torch-cuda-graph)")
    return (compile_mode or "default") if backend == "torch-compile" else None


def _on_device(module: torch.nn.Module, device: torch.device,
               channels_last: bool = False) -> torch.nn.Module:
    """``module`` on ``device`` (in channels-last format if asked): itself on the CPU in the
    default format, else a copy (the caller's module stays as it was)."""
    if device.type == "cpu" and not channels_last:
        return module
    model = copy.deepcopy(module).to(device)
    return model.to(memory_format=torch.channels_last) if channels_last else model  # type: ignore[call-overload]


def _placed(tensor: torch.Tensor, device: torch.device, channels_last: bool) -> torch.Tensor:
    tensor = tensor.to(device)
    if channels_last and tensor.dim() == 4:
        return tensor.contiguous(memory_format=torch.channels_last)
    return tensor


def _captured(model: torch.nn.Module, args: tuple[torch.Tensor, ...],
              context: Callable[[], contextlib.AbstractContextManager[None]]
              ) -> Callable[[], Any]:
    """The pass captured once as a CUDA graph (after warm-up passes on a side stream, as
    torch's documentation prescribes: cuDNN's autotuner and the allocator settle before the
    capture); returns a call replaying it and returning the graph's static output."""
    static = tuple(t.clone() for t in args)
    side = torch.cuda.Stream()  # type: ignore[no-untyped-call]
    side.wait_stream(torch.cuda.current_stream())
    with torch.cuda.stream(side), context():
        for _ in range(3):
            model(*static)
    torch.cuda.current_stream().wait_stream(side)
    graph = torch.cuda.CUDAGraph()
    with context(), torch.cuda.graph(graph):
        output = model(*static)

    def replay() -> Any:
        graph.replay()
        return output

    return replay


def _settle(call: Callable[[], object], timer: PassTimer,
            context: Callable[[], contextlib.AbstractContextManager[None]]) -> Settled:
    with context():
        return settle(call, timer)


def _check_settings(backend: str, runs: int, warmup: int, threads: int | None,
                    max_rounds: int) -> None:
    if backend not in BACKENDS:
        raise UnknownNameError(f"unknown backend {backend!r} (known: {', '.join(BACKENDS)})")
    if runs < 1 or warmup < 0 or (threads is not None and threads < 1):
        raise ValueError(f"need runs >= 1, warmup >= 0, threads >= 1 (got runs={runs}, "
                         f"warmup={warmup}, threads={threads})")
    if max_rounds < 1:
        raise ValueError(f"max_rounds must be >= 1, got {max_rounds}")


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


def _time_in_rounds(call: Callable[[], object], runs: int, warmup: int, max_rounds: int,
                    stable_rel_iqr: float | None, first: Probe,
                    context: Callable[[], contextlib.AbstractContextManager[None]],
                    timer: PassTimer) -> _Timed:
    """Rounds of ``runs`` passes (each in ``context``; ``warmup`` untimed ones before the
    first) until one's IQR / median is at most ``stable_rel_iqr``, at most ``max_rounds``; the
    stable round, else the steadiest, with the machine probes just before and after it
    (``first`` the one taken before the first round)."""
    probes = [first]  # one before every round and one after the last
    kept: list[float] = []
    kept_rel, kept_round = float("inf"), 0
    for r in range(max_rounds):
        with context():
            times = _time_calls(call, runs, warmup if r == 0 else 0, timer)
        probes.append(Probe.take())
        rel = _rel_iqr(times)
        stable = stable_rel_iqr is not None and rel <= stable_rel_iqr
        if rel < kept_rel or stable:
            kept, kept_rel, kept_round = times, rel, r
        if stable:
            break
    return _Timed(kept, len(probes) - 1, kept_rel, (probes[kept_round], probes[kept_round + 1]),
                  warmup)


def _speed_record(timed: _Timed, *, backend: str, size: tuple[int, int], threads: int,
                  macs: int, roofline: float, stable_rel_iqr: float | None,
                  calibration_log: Any, session_s: float | None) -> SpeedRecord:
    """The record of ``timed``: latency and speed percentiles, the roofline fraction, the
    machine (:func:`~evsmap.environment.collect_environment`) and its contention."""
    times_ms = [t * 1000.0 for t in timed.times]
    q25, median, q75 = (float(v) for v in np.percentile(times_ms, [25, 50, 75]))
    achieved = macs / (median / 1000.0) / 1e9
    before, after = timed.probes
    env = collect_environment(threads)
    return SpeedRecord(
        backend=backend, height=size[0], width=size[1], runs=len(times_ms),
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
        **_precision_fields(timed), session_s=session_s,
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


@contextlib.contextmanager
def _timing_context(module: torch.nn.Module, backend: str, device: torch.device | None = None,
                    autocast: str | None = None) -> Iterator[None]:
    """A torch backend's passes: the module in eval mode under ``inference_mode``, ``autocast``
    at its dtype, cuDNN's autotuner on a GPU (restored after); ONNX Runtime's passes run in
    no context (:func:`prepare_pass`)."""
    device = device or torch.device("cpu")
    with contextlib.ExitStack() as stack:
        stack.enter_context(eval_mode(module))
        stack.enter_context(torch.inference_mode())
        if autocast is not None:
            dtype = torch.float16 if autocast == "fp16" else torch.bfloat16
            # no weight-cast cache: a CUDA graph's capture must not keep casts made outside it
            stack.enter_context(torch.autocast(device_type=device.type, dtype=dtype,
                                               cache_enabled=backend != "torch-cuda-graph"))
        if device.type == "cuda":
            stack.enter_context(_cudnn_benchmark())
        yield


@contextlib.contextmanager
def _cudnn_benchmark() -> Iterator[None]:
    previous = torch.backends.cudnn.benchmark
    torch.backends.cudnn.benchmark = True
    try:
        yield
    finally:
        torch.backends.cudnn.benchmark = previous


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


def _onnxruntime_forward(
    module: torch.nn.Module, inputs: tuple[torch.Tensor, ...],
    input_names: Sequence[str] | None,
    threads: int, key: str, cache_dir: str | os.PathLike[str] | None,
    onnx_path: str | os.PathLike[str] | None = None,
    free_dimensions: dict[str, int] | None = None, *,
    provider: str | None = "cpu", device: torch.device | None = None, fp16: bool = False,
) -> tuple[Callable[[], object], str]:
    """One pass of the module's (cached) ONNX export on ``provider``, from host arrays to host
    arrays, and the provider the session runs with (checked: no silent fall-back)."""
    from evsmap.models.onnx_export import cached_onnx
    from evsmap.models.ort_providers import check_used, provider_chain
    from evsmap.models.speed_export import session_for

    provider = provider or "cpu"
    index = (device.index or 0) if device is not None else 0
    chain = provider_chain(provider, device_index=index, fp16=fp16)
    if input_names is None:
        input_names = [f"input{i}" for i in range(len(inputs))]
    path = onnx_path or cached_onnx(module, inputs, input_names, key=key, cache_dir=cache_dir)
    session = session_for(path, threads=threads, free_dimensions=free_dimensions,
                          providers=chain)
    used = check_used(session, provider)
    arrays = dict(zip(input_names, (t.detach().cpu().numpy() for t in inputs), strict=True))
    # the exporter drops inputs the graph does not use; feed only those it kept
    feeds = {i.name: arrays[i.name] for i in session.get_inputs()}
    return (lambda: session.run(None, feeds)), used
