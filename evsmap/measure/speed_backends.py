"""The ways a network's forward pass is run to be timed: one class per backend.

:func:`~evsmap.measure.speed.measure_speed` times whatever :class:`Backend` it is given; each
backend knows its own options, refuses what does not go together (on construction, or for a
device in :meth:`Backend.check`) and builds the pass (:meth:`Backend.prepare`: the module copied
to the device, compiled, captured or exported, its one-off cost paid and recorded). A new
backend is a new class here, not another parameter of the timing.

* :class:`TorchEager`: eval mode, ``torch.inference_mode``, optionally ``torch.autocast`` and
  channels-last tensors;
* :class:`TorchCompiled`: the same module through ``torch.compile`` (TorchInductor) in a mode
  (:data:`COMPILE_MODES`); the first call compiles and is recorded apart (``compile_s``);
* :class:`TorchCudaGraph`: the eager pass captured once as a CUDA graph and replayed (a GPU
  only);
* :class:`OnnxRuntime`: the module's cached ONNX export (or a given file, e.g. its int8
  quantisation, with its free dimensions pinned) on an execution provider.

:func:`make_backend` builds one from the names the command line and the sweeps use.
"""

from __future__ import annotations

import contextlib
import copy
import functools
import os
import time
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import torch

from evsmap.devices import DeviceUnavailableError, PassTimer, require_device
from evsmap.errors import InvalidDataError, UnknownNameError
from evsmap.models.module_utils import as_inputs, eval_mode

BACKENDS = ("onnxruntime", "torch", "torch-compile", "torch-cuda-graph")
"""The backends' names (:attr:`Backend.name`), as ``evsmap speed --backend`` takes them."""
COMPILE_MODES = ("default", "reduce-overhead", "max-autotune")
"""``torch.compile``'s modes (``reduce-overhead`` replays CUDA graphs on a GPU)."""
AUTOCASTS = ("fp16", "bf16")
"""``autocast`` values: torch's mixed precision (``torch.autocast``) at this dtype."""

Context = Callable[[], contextlib.AbstractContextManager[None]]


@dataclass
class PreparedPass:
    """One forward pass ready to time: ``call`` runs it and returns its output (logits, or ONNX
    Runtime's arrays), ``context`` is what every call runs in (eval mode, inference mode,
    autocast, cuDNN's autotuner); ``compile_s`` the first call of a compiled module,
    ``session_s`` ONNX Runtime's session, ``provider`` the provider it runs with."""

    call: Callable[[], Any]
    context: Context
    provider: str | None = None
    compile_mode: str | None = None
    compile_s: float | None = None
    session_s: float | None = None


class Backend(ABC):
    """How a pass is run (module docstring); subclasses are frozen dataclasses of their
    options."""

    name: ClassVar[str]
    autocast: str | None

    def check(self, device: torch.device) -> None:  # noqa: B027 - most backends run anywhere
        """Refuse, in one line, a device this backend does not run on (nothing by default)."""

    def prepare(self, module: torch.nn.Module, inputs: torch.Tensor | Sequence[torch.Tensor],
                device: str = "cpu", timer: PassTimer | None = None) -> PreparedPass:
        """``module(*inputs)`` on ``device``, ready to time, its one-off cost paid here.

        Raises:
            UnknownNameError: an unknown device.
            DeviceUnavailableError: the device or provider is not on this machine, or a
                GPU-only backend asked for on the CPU.
            InvalidDataError: a setting that does not go with the device.
        """
        dev = require_device(device)
        self.check(dev)
        return self._build(module, as_inputs(inputs), dev, timer or PassTimer(dev))

    @abstractmethod
    def _build(self, module: torch.nn.Module, inputs: tuple[torch.Tensor, ...],
               device: torch.device, timer: PassTimer) -> PreparedPass:
        """The pass, the device checked."""

    def record_fields(self) -> dict[str, Any]:
        """What a speed record states of the backend (``backend``, ``autocast``,
        ``channels_last``)."""
        return {"backend": self.name, "autocast": self.autocast, "channels_last": False}


def _check_autocast(autocast: str | None) -> None:
    if autocast is not None and autocast not in AUTOCASTS:
        raise UnknownNameError(f"unknown autocast {autocast!r} (known: {', '.join(AUTOCASTS)})")


@dataclass(frozen=True)
class TorchEager(Backend):
    """torch's eager pass: the module in eval mode under ``inference_mode``, at ``autocast``'s
    dtype when given, its 4-D inputs and weights in channels-last format with
    ``channels_last``; on a GPU a copy of the module there, cuDNN's autotuner on."""

    name: ClassVar[str] = "torch"
    autocast_cache: ClassVar[bool] = True
    """Whether autocast keeps its casts of the weights between calls."""
    autocast: str | None = None
    channels_last: bool = False

    def __post_init__(self) -> None:
        _check_autocast(self.autocast)

    def record_fields(self) -> dict[str, Any]:
        return {**super().record_fields(), "channels_last": self.channels_last}

    def _build(self, module: torch.nn.Module, inputs: tuple[torch.Tensor, ...],
               device: torch.device, timer: PassTimer) -> PreparedPass:
        model, args, context = self._placed(module, inputs, device)
        return PreparedPass(functools.partial(model, *args), context)

    def _placed(self, module: torch.nn.Module, inputs: tuple[torch.Tensor, ...],
                device: torch.device
                ) -> tuple[torch.nn.Module, tuple[torch.Tensor, ...], Context]:
        """The module and inputs on ``device`` in this backend's format, and the context its
        passes run in."""
        model = _on_device(module, device, self.channels_last)
        args = tuple(_placed(t, device, self.channels_last) for t in inputs)
        return model, args, functools.partial(self._context, model, device)

    @contextlib.contextmanager
    def _context(self, model: torch.nn.Module, device: torch.device) -> Iterator[None]:
        with contextlib.ExitStack() as stack:
            stack.enter_context(eval_mode(model))
            stack.enter_context(torch.inference_mode())
            if self.autocast is not None:
                dtype = torch.float16 if self.autocast == "fp16" else torch.bfloat16
                stack.enter_context(torch.autocast(device_type=device.type, dtype=dtype,
                                                   cache_enabled=self.autocast_cache))
            if device.type == "cuda":
                stack.enter_context(_cudnn_benchmark())
            yield


@dataclass(frozen=True)
class TorchCompiled(TorchEager):
    """The eager pass through ``torch.compile`` (TorchInductor) in ``mode``
    (:data:`COMPILE_MODES`); the first call compiles, timed apart (``compile_s``)."""

    name: ClassVar[str] = "torch-compile"
    mode: str = "default"

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.mode not in COMPILE_MODES:
            raise UnknownNameError(f"unknown compile mode {self.mode!r} (known: "
                                   f"{', '.join(COMPILE_MODES)})")

    def _build(self, module: torch.nn.Module, inputs: tuple[torch.Tensor, ...],
               device: torch.device, timer: PassTimer) -> PreparedPass:
        model, args, context = self._placed(module, inputs, device)
        compiled = functools.partial(torch.compile(model, mode=self.mode), *args)
        with context():
            compile_s = timer(compiled)  # the first call compiles
        return PreparedPass(compiled, context, compile_mode=self.mode, compile_s=compile_s)


@dataclass(frozen=True)
class TorchCudaGraph(TorchEager):
    """The eager pass captured once as a CUDA graph and replayed (a GPU only)."""

    name: ClassVar[str] = "torch-cuda-graph"
    autocast_cache: ClassVar[bool] = False
    """A capture must not keep casts made outside it."""

    def check(self, device: torch.device) -> None:
        if device.type != "cuda":
            raise DeviceUnavailableError(f"backend {self.name} replays a captured CUDA graph: "
                                         f"it needs a GPU (--device cuda), not {device}")

    def _build(self, module: torch.nn.Module, inputs: tuple[torch.Tensor, ...],
               device: torch.device, timer: PassTimer) -> PreparedPass:
        model, args, context = self._placed(module, inputs, device)
        return PreparedPass(_captured(model, args, context), context)


@dataclass(frozen=True)
class OnnxRuntime(Backend):
    """The module's ONNX export on ONNX Runtime, all graph optimisations, inputs from host
    arrays (:mod:`evsmap.models.speed_export`'s session).

    Attributes:
        provider: the execution provider (:data:`evsmap.models.ort_providers.PROVIDERS`;
            None: ``cpu`` on the CPU, ``cuda`` on a GPU); checked to be the one the session
            runs on (no silent fall-back).
        autocast: ``fp16`` with the ``tensorrt`` provider builds fp16 engines; nothing else.
        onnx_path: time this ONNX file (e.g. the module's int8 quantisation) instead of the
            module's cached fp32 export (:func:`~evsmap.models.onnx_export.cached_onnx`).
        free_dimensions: the graph's free dimensions pinned for the session (a size-free
            export timed at one size: :func:`~evsmap.models.speed_export.speed_export`).
        input_names: the graph's input names (default ``input0``, ``input1``, ...).
        key: the export cache's entry (default: the module's class name).
        cache_dir: the export cache (default
            :func:`~evsmap.models.onnx_export.default_cache_dir`).
    """

    name: ClassVar[str] = "onnxruntime"
    provider: str | None = None
    autocast: str | None = None
    onnx_path: str | os.PathLike[str] | None = None
    free_dimensions: Mapping[str, int] | None = None
    input_names: Sequence[str] | None = None
    key: str | None = None
    cache_dir: str | os.PathLike[str] | None = None

    def __post_init__(self) -> None:
        from evsmap.models.ort_providers import PROVIDERS

        _check_autocast(self.autocast)
        if self.provider is not None and self.provider not in PROVIDERS:
            raise UnknownNameError(f"unknown ONNX Runtime provider {self.provider!r} (known: "
                                   f"{', '.join(PROVIDERS)})")

    def provider_on(self, device: torch.device) -> str:
        """The provider the session uses on ``device``."""
        from evsmap.models.ort_providers import default_provider

        return self.provider or default_provider(str(device))

    def check(self, device: torch.device) -> None:
        provider = self.provider_on(device)
        if (provider == "cpu") != (device.type == "cpu"):
            raise InvalidDataError(f"provider {provider} does not run on device {device}: the "
                                   f"cpu provider runs on the CPU, cuda and tensorrt on a GPU "
                                   f"(pass the device: --device cpu or cuda)")
        if self.autocast is not None and (provider, self.autocast) != ("tensorrt", "fp16"):
            raise InvalidDataError(f"{self.autocast} on ONNX Runtime: only TensorRT builds fp16 "
                                   f"engines (provider tensorrt); the {provider} provider runs "
                                   f"the fp32 export (use backend torch or torch-compile for "
                                   f"{self.autocast})")

    def _build(self, module: torch.nn.Module, inputs: tuple[torch.Tensor, ...],
               device: torch.device, timer: PassTimer) -> PreparedPass:
        """One pass from host arrays to host arrays, the session's load timed (``session_s``:
        not cached across runs, a second or two even for the largest network here)."""
        from evsmap.models.onnx_export import cached_onnx
        from evsmap.models.ort_providers import check_used, provider_chain
        from evsmap.models.speed_export import session_for

        t0 = time.perf_counter()
        provider = self.provider_on(device)
        chain = provider_chain(provider, device_index=device.index or 0,
                               fp16=self.autocast == "fp16")
        names = list(self.input_names or [f"input{i}" for i in range(len(inputs))])
        path = self.onnx_path or cached_onnx(module, inputs, names,
                                             key=self.key or type(module).__name__,
                                             cache_dir=self.cache_dir)
        session = session_for(path, threads=torch.get_num_threads(),
                              free_dimensions=self.free_dimensions, providers=chain)
        used = check_used(session, provider)
        arrays = dict(zip(names, (t.detach().cpu().numpy() for t in inputs), strict=True))
        # the exporter drops inputs the graph does not use; feed only those it kept
        feeds = {i.name: arrays[i.name] for i in session.get_inputs()}
        return PreparedPass(lambda: session.run(None, feeds), contextlib.nullcontext,
                            provider=used, session_s=time.perf_counter() - t0)


def make_backend(name: str = "torch", *, autocast: str | None = None,
                 channels_last: bool = False, compile_mode: str | None = None,
                 provider: str | None = None, onnx: Mapping[str, Any] | None = None) -> Backend:
    """The backend ``name`` (:data:`BACKENDS`) with its options, as the command line and the
    sweeps name them; ``onnx`` holds :class:`OnnxRuntime`'s export and session fields
    (``input_names``, ``key``, ``cache_dir``, ``onnx_path``, ``free_dimensions``), read for
    ``onnxruntime`` only (the torch backends run the module itself).

    Raises:
        UnknownNameError: an unknown backend, autocast, compile mode or provider.
        InvalidDataError: an option of another backend (a compile mode without
            torch-compile, a provider without onnxruntime, channels-last on ONNX Runtime).
    """
    if name not in BACKENDS:
        raise UnknownNameError(f"unknown backend {name!r} (known: {', '.join(BACKENDS)})")
    if compile_mode is not None and name != TorchCompiled.name:
        _check_compile_mode(compile_mode)
        raise InvalidDataError(f"compile mode {compile_mode} is torch.compile's: it needs "
                               f"backend torch-compile (backend {name!r} given)")
    if name == OnnxRuntime.name:
        if channels_last:
            raise InvalidDataError("channels-last is a torch memory format: ONNX Runtime "
                                   "chooses its own layouts (use backend torch, torch-compile "
                                   "or torch-cuda-graph)")
        return OnnxRuntime(provider=provider, autocast=autocast, **dict(onnx or {}))
    if provider is not None:
        _check_autocast(autocast)
        raise InvalidDataError(f"provider {provider!r} is ONNX Runtime's: it needs backend "
                               f"onnxruntime (backend {name!r} given)")
    if name == TorchCompiled.name:
        return TorchCompiled(autocast=autocast, channels_last=channels_last,
                             mode=compile_mode or "default")
    if name == TorchCudaGraph.name:
        return TorchCudaGraph(autocast=autocast, channels_last=channels_last)
    return TorchEager(autocast=autocast, channels_last=channels_last)


def _check_compile_mode(mode: str) -> None:
    if mode not in COMPILE_MODES:
        raise UnknownNameError(f"unknown compile mode {mode!r} (known: "
                               f"{', '.join(COMPILE_MODES)})")


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
              context: Context) -> Callable[[], Any]:
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


@contextlib.contextmanager
def _cudnn_benchmark() -> Iterator[None]:
    previous = torch.backends.cudnn.benchmark
    torch.backends.cudnn.benchmark = True
    try:
        yield
    finally:
        torch.backends.cudnn.benchmark = previous
