"""Every way of running one network on one device, timed under one rule, with its labels checked
against eager fp32's, and the fastest variant whose labels qualify.

A launch-bound GPU pass (a small network, batch 1) is as fast as the host launches its kernels;
GPU engineers remove that overhead with a CUDA graph (captured once, replayed), torch.compile's
``reduce-overhead`` and ``max-autotune`` modes, channels-last tensors for tensor-core
convolutions, and fp16/bf16 where the labels survive it. :func:`backend_sweep` times each such
:class:`Variant` (:func:`variants`) with :func:`~evsmap.measure.speed.measure_speed` and the same
:class:`~evsmap.measure.timing_policy.TimingPolicy`, or records in one line why it does not run
here (a GPU-only variant on the CPU, a missing library or provider, out of memory). For each
timed variant it runs one pass more, built the same way (:meth:`~evsmap.measure.
speed_backends.Backend.prepare`), and compares its per-pixel argmax with eager fp32's on the
same input:

* an fp32 variant qualifies when its labels are **equal** to eager fp32's, every pixel;
* a reduced-precision one (fp16/bf16 autocast, TensorRT's fp16 engines) when at least
  :data:`REDUCED_PRECISION_AGREEMENT` of the pixels keep their label.

The fastest qualifying variant (:func:`fastest_qualifying`: the lowest median pass time) is
named beside every other. A compiled variant's compilation is recorded (``compile_s``), never
in its pass time. Records only; ``evsmap speed --sweep-backends`` formats them.
"""

from __future__ import annotations

import fnmatch
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
import torch

from evsmap.devices import require_device
from evsmap.errors import EvsmapError, UnknownNameError
from evsmap.measure.batch_sweep import first_line, free_device_memory, is_out_of_memory
from evsmap.measure.speed import SpeedRecord, measure_speed
from evsmap.measure.speed_backends import Backend, make_backend
from evsmap.measure.timing_policy import TimingPolicy

PRECISIONS = ("fp32", "fp16", "bf16")
REDUCED_PRECISION_AGREEMENT = 0.999
"""The share of pixels whose label a reduced-precision variant (fp16/bf16 autocast, TensorRT
fp16) must keep to qualify. fp16 keeps 11 significant bits and bf16 8, so the logits move by
about 1e-3 and 4e-3 of their size: the argmax changes only where a pixel's two best classes are
that close, a thin scatter along class boundaries. 99.9 % allows one pixel in a thousand to
flip there and still catches a variant that is wrong somewhere (an overflow, a layer whose
output saturates in fp16), which moves whole regions. An fp32 variant must be equal."""
REFERENCE = "eager-fp32"

Measure = Callable[..., SpeedRecord]


@dataclass(frozen=True)
class Variant:
    """One way of running the network: a backend (:data:`~evsmap.measure.speed_backends.
    BACKENDS`) with its options (``name`` is how it is asked for and reported)."""

    name: str
    backend: str
    precision: str = "fp32"
    compile_mode: str | None = None
    channels_last: bool = False
    provider: str | None = None

    @property
    def reduced_precision(self) -> bool:
        return self.precision != "fp32"

    @property
    def required_agreement(self) -> float:
        """The share of pixels that must keep eager fp32's label (1.0: all of them)."""
        return REDUCED_PRECISION_AGREEMENT if self.reduced_precision else 1.0

    def make(self, onnx: Mapping[str, Any] | None = None) -> Backend:
        """The :class:`~evsmap.measure.speed_backends.Backend` that runs this variant;
        ``onnx``: ONNX Runtime's export and session fields (``key``, ``input_names``,
        ``cache_dir``; :func:`~evsmap.measure.speed_backends.make_backend`)."""
        return make_backend(self.backend, autocast=self.precision if self.reduced_precision
                            else None, channels_last=self.channels_last,
                            compile_mode=self.compile_mode, provider=self.provider, onnx=onnx)


def variants() -> list[Variant]:
    """Every variant, eager fp32 (the reference) first: for each precision eager, channels-last,
    the CUDA graph (also with channels-last), torch.compile in each mode; then ONNX Runtime on
    each provider in fp32, and TensorRT's fp16 engines."""
    out = []
    for p in PRECISIONS:
        out += [Variant(f"eager-{p}", "torch", p),
                Variant(f"channels-last-{p}", "torch", p, channels_last=True),
                Variant(f"cuda-graph-{p}", "torch-cuda-graph", p),
                Variant(f"cuda-graph-channels-last-{p}", "torch-cuda-graph", p,
                        channels_last=True)]
        out += [Variant(f"compile-{mode}-{p}", "torch-compile", p, compile_mode=mode)
                for mode in ("default", "reduce-overhead", "max-autotune")]
    out += [Variant(f"onnxruntime-{provider}-fp32", "onnxruntime", provider=provider)
            for provider in ("cpu", "cuda", "tensorrt")]
    out.append(Variant("onnxruntime-tensorrt-fp16", "onnxruntime", "fp16", provider="tensorrt"))
    return sorted(out, key=lambda v: v.name != REFERENCE)


def select_variants(patterns: Sequence[str] | None) -> list[Variant]:
    """The variants whose names match any of the shell-style ``patterns`` (``cuda-graph-*``,
    ``*-fp16``, ``eager-fp32``), eager fp32 always first; every variant when None.

    Raises:
        UnknownNameError: a pattern that matches no variant.
    """
    every = variants()
    if not patterns:
        return every
    names = [v.name for v in every]
    for pattern in patterns:
        if not fnmatch.filter(names, pattern):
            raise UnknownNameError(f"backend variant {pattern!r} matches none (known: "
                                   f"{', '.join(names)}; shell patterns such as 'cuda-graph-*' "
                                   f"or '*-fp16' select several)")
    return [v for v in every if v.name == REFERENCE
            or any(fnmatch.fnmatchcase(v.name, p) for p in patterns)]


@dataclass(frozen=True)
class VariantResult:
    """One variant of the sweep.

    Attributes:
        variant: its name; ``backend``, ``precision``, ``compile_mode``, ``channels_last``,
            ``provider``: what it is.
        status: ``timed``, ``refused`` (does not run here: the device, a missing library or
            provider, out of memory) or ``failed`` (an error while building or timing it).
        why: the one line of a refused or failed variant.
        ms_median: its median pass, ms; ``speedup``: eager fp32's median over it.
        compile_s: the compilation (torch.compile's first call), not in ``ms_median``.
        label_agreement: the share of pixels whose argmax equals eager fp32's.
        required_agreement: the share it needs to qualify (1.0: equal).
        qualifies: timed and ``label_agreement >= required_agreement``.
        bound: ``launch``, ``device`` or ``host`` (the speed record's).
        speed: the full speed record.
    """

    variant: str
    backend: str
    precision: str
    compile_mode: str | None
    channels_last: bool
    provider: str | None
    status: str
    why: str | None = None
    ms_median: float | None = None
    speedup: float | None = None
    compile_s: float | None = None
    label_agreement: float | None = None
    required_agreement: float = 1.0
    qualifies: bool = False
    bound: str | None = None
    speed: SpeedRecord | None = None

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True)
class BackendSweep:
    """One network's sweep: every variant's result in the order run, and the fastest that
    qualifies (None when only failures: eager fp32 qualifies by definition)."""

    network: str
    device: str
    policy: dict[str, Any]
    results: list[VariantResult] = field(default_factory=list)
    fastest: str | None = None
    reduced_precision_agreement: float = REDUCED_PRECISION_AGREEMENT

    def result(self, variant: str) -> VariantResult:
        for r in self.results:
            if r.variant == variant:
                return r
        raise KeyError(f"no result for variant {variant}")

    def as_dict(self) -> dict[str, Any]:
        return {"network": self.network, "device": self.device, "policy": self.policy,
                "reference": REFERENCE, "fastest": self.fastest,
                "reduced_precision_agreement": self.reduced_precision_agreement,
                "results": [r.as_dict() for r in self.results]}


def fastest_qualifying(results: Sequence[VariantResult]) -> VariantResult | None:
    """The qualifying result with the lowest median pass (the first of equals), or None."""
    best: VariantResult | None = None
    for r in results:
        if r.qualifies and r.ms_median is not None and (best is None or best.ms_median is None
                                                        or r.ms_median < best.ms_median):
            best = r
    return best


def backend_sweep(network: str, module: torch.nn.Module, inputs: Sequence[torch.Tensor], *,
                  selected: Sequence[Variant] | None = None, device: str = "cpu",
                  policy: TimingPolicy | None = None, measure: Measure = measure_speed,
                  onnx: Mapping[str, Any] | None = None, **speed_options: Any) -> BackendSweep:
    """Time every variant of ``module(*inputs)`` on ``device`` and check its labels (module
    docstring).

    Args:
        network: the network's name (the ONNX cache key).
        selected: the variants (default :func:`variants`); eager fp32 is run first whatever
            the selection, as the reference of the labels and speed-ups.
        policy: the timing rule of every variant (default :class:`TimingPolicy`'s).
        measure: the timing function (:func:`~evsmap.measure.speed.measure_speed`).
        onnx: the ONNX Runtime variants' export fields (``input_names``, ``cache_dir``; the
            cache key is ``network``).
        speed_options: more keyword arguments of ``measure`` (``threads``, ``macs``,
            ``roofline``, ...), the same for every variant.

    Raises:
        DeviceUnavailableError: the device is not on this machine (eager fp32 itself cannot
            run).
    """
    require_device(device)  # before any work: a device that is not here is one line
    chosen = list(selected) if selected is not None else variants()
    reference = next(v for v in variants() if v.name == REFERENCE)
    chosen = [reference, *(v for v in chosen if v.name != REFERENCE)]
    policy = policy or TimingPolicy()
    if "macs" not in speed_options:
        from evsmap.measure.complexity import measure_complexity

        speed_options["macs"] = measure_complexity(module, inputs).flops
    if "roofline" not in speed_options:
        from evsmap.measure.speed import roofline_gmacs

        speed_options["roofline"] = roofline_gmacs(device=device)
    onnx = {**(onnx or {}), "key": network}
    ref_backend = reference.make(onnx)
    ref_record = measure(module, inputs, backend=ref_backend, device=device, policy=policy,
                         **speed_options)
    ref_labels = variant_labels(module, inputs, ref_backend, device)
    results = [_timed(reference, ref_record, 1.0, ref_record.ms_median)]
    for variant in chosen[1:]:
        results.append(_run_variant(variant, module, inputs, ref_labels, ref_record.ms_median,
                                    device, policy, measure, speed_options, onnx))
        free_device_memory(device)
    best = fastest_qualifying(results)
    return BackendSweep(network, device, policy.as_dict(), results,
                        best.variant if best else None)


def _run_variant(variant: Variant, module: torch.nn.Module, inputs: Sequence[torch.Tensor],
                 ref_labels: torch.Tensor, ref_ms: float, device: str, policy: TimingPolicy,
                 measure: Measure, speed_options: dict[str, Any],
                 onnx: Mapping[str, Any]) -> VariantResult:
    """One variant timed, then its labels compared (refused or failed in one line)."""
    why = refusal(variant, device)
    if why is not None:
        return VariantResult(**_identity(variant), status="refused", why=why,
                             required_agreement=variant.required_agreement)
    try:
        backend = variant.make(onnx)
        record = measure(module, inputs, backend=backend, device=device, policy=policy,
                         **speed_options)
        labels = variant_labels(module, inputs, backend, device)
    except Exception as exc:  # noqa: BLE001 - one variant's failure is its row, not the sweep's
        return _not_timed(variant, exc)
    return _timed(variant, record, label_agreement(labels, ref_labels), ref_ms)


def refusal(variant: Variant, device: str) -> str | None:
    """Why ``variant`` is not run on ``device`` before trying it, or None (the rest is refused
    by the backend itself, :meth:`~evsmap.measure.speed_backends.Backend.prepare`):
    torch.compile's ``reduce-overhead`` mode is its default one plus CUDA graphs, so on the
    CPU it would time compile-default again under another name."""
    if variant.compile_mode == "reduce-overhead" and not device.startswith("cuda"):
        return ("compile mode reduce-overhead replays CUDA graphs: on the CPU it is "
                "compile-default's pass (needs --device cuda)")
    return None


def _timed(variant: Variant, record: SpeedRecord, agreement: float,
           ref_ms: float) -> VariantResult:
    return VariantResult(
        **_identity(variant), status="timed", ms_median=record.ms_median,
        speedup=ref_ms / record.ms_median, compile_s=record.compile_s,
        label_agreement=agreement, required_agreement=variant.required_agreement,
        qualifies=agreement >= variant.required_agreement, bound=record.busy.get("bound"),
        speed=record)


def _not_timed(variant: Variant, exc: BaseException) -> VariantResult:
    """A refusal (an evsmap error: the device, a library, a provider; out of memory) or a
    failure (anything else), in one line."""
    if is_out_of_memory(exc):
        status, why = "refused", f"out of memory: {first_line(exc)}"
    elif isinstance(exc, EvsmapError):
        status, why = "refused", first_line(exc)
    else:
        status, why = "failed", f"{type(exc).__name__}: {first_line(exc)}"
    return VariantResult(**_identity(variant), status=status, why=why,
                         required_agreement=variant.required_agreement)


def _identity(variant: Variant) -> dict[str, Any]:
    return {"variant": variant.name, "backend": variant.backend,
            "precision": variant.precision, "compile_mode": variant.compile_mode,
            "channels_last": variant.channels_last, "provider": variant.provider}


def variant_labels(module: torch.nn.Module, inputs: Sequence[torch.Tensor], backend: Backend,
                   device: str) -> torch.Tensor:
    """The per-pixel argmax of one pass on ``backend``, built as its timing builds it
    (:meth:`~evsmap.measure.speed_backends.Backend.prepare`; a compiled variant is compiled
    again, from TorchInductor's cache), on the host."""
    prepared = backend.prepare(module, inputs, device)
    with prepared.context():
        output = prepared.call()
    return argmax_labels(output)


def argmax_labels(output: Any) -> torch.Tensor:
    """The class index of each pixel of a network's output (logits ``(B, C, H, W)``, a tuple
    or list whose first item they are, or ONNX Runtime's arrays), on the host."""
    if isinstance(output, tuple | list):
        output = output[0]
    logits = torch.from_numpy(np.asarray(output)) if isinstance(output, np.ndarray) else output
    if not isinstance(logits, torch.Tensor) or logits.dim() < 2:
        raise TypeError(f"expected logits (B, C, ...), got {type(output).__name__}")
    return logits.detach().float().argmax(dim=1).cpu()


def label_agreement(labels: torch.Tensor, reference: torch.Tensor) -> float:
    """The share of pixels where ``labels`` equals ``reference``.

    Raises:
        ValueError: the two are of different shapes.
    """
    if labels.shape != reference.shape:
        raise ValueError(f"labels of shape {tuple(labels.shape)} against the reference's "
                         f"{tuple(reference.shape)}")
    return float((labels == reference).double().mean())
