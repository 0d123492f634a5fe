"""The ONNX export the speed cells time: one per network for every input size, exported lean,
cached across runs.

* **One export per network.** The graph is exported with free ``height`` / ``width``
  dimensions and timed at each size through a session that pins them
  (``add_free_dimension_override_by_name``), so ONNX Runtime optimises it as a fixed-size graph.
  A network whose graph is not size-free (a Python branch on a shape, a size baked into a layer)
  is caught by a check: the export is traced at one small size and compared with the torch
  module at another (:func:`_verify`); one that differs, or fails to export that way, falls back
  to a fixed-size export at the timed size, and the record says why.
* **Lean.** The graph is traced without its weights (``export_params=False``), then every weight
  is written, tensor by tensor, to a data file beside the graph (ONNX external data). Traced at
  a quarter of the pixels, this keeps the export's memory near the network's own size: RDFNet
  (1.43 GB of weights) peaked at 9.0 GB with the embedded TorchScript export at 640x480, 5.1 GB
  lean at full size, and the lean size-free export needs the network and one small trace.
* **Cached** under ``<cache>/onnx`` by what determines the graph (:func:`export_key`): a
  second run, or the other input size of the same network, reuses it. The time an export took
  is returned, so a record can state it.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import os
import re
import shutil
import tempfile
import time
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np
import torch

from evsmap.fileio import quiet_native_output
from evsmap.interrupt import reraise_interruption
from evsmap.models.module_utils import as_inputs, eval_mode
from evsmap.models.onnx_export import (
    OPSET,
    OUTPUT_NAMES,
    OnnxExportError,
    state_digest,
    structure_digest,
)

HEIGHT, WIDTH = "height", "width"
"""The free dimensions of a size-free export (the output's are ``out_height`` and
``out_width``)."""
EXPORT_FORMAT = "lean-1"
"""Changes when the export method does, so old cache entries are not reused."""
TRACE_STEP = 64
"""Trace and check sizes are multiples of this (every network here accepts them)."""


@dataclass(frozen=True)
class SpeedExport:
    """An export ready to time.

    Attributes:
        path: the graph (its weights in ``<path>.data`` beside it).
        size_free: one graph for every input size (``free_dimensions`` pins it).
        export_s: seconds this call spent exporting and checking (None: from the cache).
        note: why the export is fixed-size, when it is.
    """

    path: Path
    size_free: bool
    export_s: float | None
    note: str = ""

    def free_dimensions(self, height: int, width: int) -> dict[str, int]:
        """The session's dimension overrides for a ``height`` x ``width`` input."""
        return {HEIGHT: height, WIDTH: width} if self.size_free else {}


def export_key(module: torch.nn.Module, inputs: Sequence[torch.Tensor],
               input_names: Sequence[str], *, key: str, size: tuple[int, ...] | None) -> str:
    """The cache entry's hash: ``key``, the module's class, structure and weights, the input
    names, dtypes and channels (and the size, for a fixed-size export), opset, torch version."""
    h = hashlib.sha256()
    shapes = ";".join(f"{t.dtype}{tuple(t.shape[:-2])}" for t in inputs)
    for part in (EXPORT_FORMAT, key, f"{type(module).__module__}.{type(module).__qualname__}",
                 ",".join(input_names), shapes, "size-free" if size is None else f"{size}",
                 str(OPSET), torch.__version__, structure_digest(module), state_digest(module)):
        h.update(part.encode())
        h.update(b"\0")
    return h.hexdigest()[:20]


def speed_export(module: torch.nn.Module, inputs: torch.Tensor | Sequence[torch.Tensor],
                 input_names: Sequence[str], *, key: str,
                 cache_dir: str | os.PathLike[str] | None = None) -> SpeedExport:
    """The cached export of ``module`` for timing at ``inputs``' size (module docstring).

    Raises:
        OnnxExportError: the network exports neither size-free nor at this size.
    """
    from evsmap.models.onnx_export import default_cache_dir

    inputs = as_inputs(inputs)
    names = list(input_names)
    if len(names) != len(inputs):
        raise ValueError(f"{len(inputs)} inputs but {len(names)} input names")
    cache = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    stem = re.sub(r"[^A-Za-z0-9._-]+", "_", key).strip("._")[:64] or "model"
    size = tuple(int(v) for v in inputs[0].shape[-2:])
    free = cache / f"{stem}-{export_key(module, inputs, names, key=key, size=None)}.onnx"
    refused = free.with_suffix(".fixed.json")
    if free.is_file():
        return SpeedExport(free, True, None)
    why = json.loads(refused.read_text())["why"] if refused.is_file() else None
    t0 = time.perf_counter()
    if why is None and _image_inputs(inputs):
        try:
            _publish(module, inputs, names, free, size_free=True)
            return SpeedExport(free, True, time.perf_counter() - t0)
        except OnnxExportError as exc:
            why = str(exc)
            _write_json(refused, {"why": why})
    elif why is None:
        why = "its inputs are not all N x C x H x W images"
    fixed = cache / f"{stem}-{export_key(module, inputs, names, key=key, size=size)}.onnx"
    note = f"fixed-size export: {why}"
    if fixed.is_file():
        return SpeedExport(fixed, False, None, note)
    _publish(module, inputs, names, fixed, size_free=False)
    return SpeedExport(fixed, False, time.perf_counter() - t0, note)


def _image_inputs(inputs: Sequence[torch.Tensor]) -> bool:
    size = inputs[0].shape[-2:]
    return all(t.dim() == 4 and t.shape[-2:] == size for t in inputs)


def trace_sizes(size: tuple[int, int]) -> tuple[tuple[int, int], tuple[int, int]]:
    """The small size a size-free export is traced at (about half of ``size`` each way) and the
    other size it is checked at (one step taller and one narrower)."""
    h, w = (max(2 * TRACE_STEP, v // 2 // TRACE_STEP * TRACE_STEP) for v in size)
    return (h, w), (h + TRACE_STEP, max(TRACE_STEP, w - TRACE_STEP))


def _resized(inputs: Sequence[torch.Tensor], size: tuple[int, int]) -> tuple[torch.Tensor, ...]:
    """``inputs`` at ``size`` (nearest neighbour: depth stays depth, labels stay labels)."""
    return tuple(torch.nn.functional.interpolate(t, size=size, mode="nearest")
                 if t.is_floating_point() else
                 torch.nn.functional.interpolate(t.float(), size=size, mode="nearest").to(t.dtype)
                 for t in inputs)


def _publish(module: torch.nn.Module, inputs: tuple[torch.Tensor, ...], names: list[str],
             path: Path, *, size_free: bool) -> None:
    """Export into a temporary folder beside ``path``, check, then move the weights and then
    the graph into place (the graph appearing last: a graph in the cache is complete)."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(dir=path.parent, prefix=".tmp-export-"))
    except OSError as exc:
        raise OnnxExportError(f"cannot write the ONNX cache folder {path.parent}: {exc}") \
            from exc
    try:
        graph = tmp / path.name
        if size_free:
            height, width = inputs[0].shape[-2:]
            traced, checked = trace_sizes((height, width))
            export_lean(module, _resized(inputs, traced), names, graph, size_free=True)
            _verify(module, _resized(inputs, checked), names, graph)
        else:
            export_lean(module, inputs, names, graph, size_free=False)
        data = graph.with_name(graph.name + ".data")
        os.replace(data, path.with_name(path.name + ".data"))
        os.replace(graph, path)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def export_lean(module: torch.nn.Module, inputs: Sequence[torch.Tensor], names: Sequence[str],
                path: Path, *, size_free: bool) -> None:
    """``module`` as an ONNX graph at ``path`` with its weights in ``<path>.data`` (module
    docstring), free height and width when ``size_free``.

    Raises:
        OnnxExportError: the exporter failed, or the graph misses a weight.
    """
    import onnx

    inputs = tuple(inputs)
    dynamic = None
    if size_free:
        dynamic = {n: {2: HEIGHT, 3: WIDTH} for n in names}
        dynamic[OUTPUT_NAMES[0]] = {2: f"out_{HEIGHT}", 3: f"out_{WIDTH}"}
    with eval_mode(module), torch.no_grad(), warnings.catch_warnings(), \
            contextlib.redirect_stdout(io.StringIO()), quiet_native_output():
        warnings.simplefilter("ignore")
        try:
            torch.onnx.export(module, inputs, str(path), input_names=list(names),
                              output_names=list(OUTPUT_NAMES), opset_version=OPSET,
                              dynamo=False, export_params=False,
                              keep_initializers_as_inputs=True, do_constant_folding=False,
                              dynamic_axes=dynamic)
        except Exception as exc:  # any exporter failure is reported, not a crash
            reraise_interruption(exc)
            raise OnnxExportError(f"ONNX export of {type(module).__name__} failed "
                                  f"({type(exc).__name__}: {_first_line(exc)})") from exc
    model = onnx.load(str(path))
    _attach_weights(model, module.state_dict(), set(names), path)
    onnx.save(model, str(path))
    try:
        onnx.checker.check_model(str(path))
    except Exception as exc:
        raise OnnxExportError(f"ONNX export of {type(module).__name__} does not check: "
                              f"{_first_line(exc)}") from exc


def _attach_weights(model, state: Mapping[str, torch.Tensor], names: set[str],
                    path: Path) -> None:
    """Turn the graph's weight inputs into initializers stored in ``<path>.data``, one tensor
    written at a time."""
    from onnx import TensorProto, helper

    data_name = path.name + ".data"
    kept, offset = [], 0
    with open(path.with_name(data_name), "wb") as data:
        for value in list(model.graph.input):
            if value.name in names:
                kept.append(value)
                continue
            if value.name not in state:
                raise OnnxExportError(f"ONNX export: graph input {value.name!r} is neither an "
                                      f"image input nor a weight")
            array = state[value.name].detach().cpu().contiguous().numpy()
            raw = np.ascontiguousarray(array).tobytes()
            tensor = TensorProto(name=value.name, dims=list(array.shape),
                                 data_type=helper.np_dtype_to_tensor_dtype(array.dtype),
                                 data_location=TensorProto.EXTERNAL)
            for k, v in (("location", data_name), ("offset", str(offset)),
                         ("length", str(len(raw)))):
                entry = tensor.external_data.add()
                entry.key, entry.value = k, v
            data.write(raw)
            offset += len(raw)
            model.graph.initializer.append(tensor)
    del model.graph.input[:]
    model.graph.input.extend(kept)


def _verify(module: torch.nn.Module, inputs: tuple[torch.Tensor, ...], names: list[str],
            path: Path) -> None:
    """The size-free graph at a size it was not traced at against the torch module there.

    Raises:
        OnnxExportError: they differ, or the graph does not run at that size.
    """
    h, w = (int(v) for v in inputs[0].shape[-2:])
    with eval_mode(module), torch.inference_mode():
        expected = module(*inputs)
    expected = (expected[0] if isinstance(expected, (tuple, list)) else expected).numpy()
    try:
        session = session_for(path, threads=torch.get_num_threads(),
                              free_dimensions={HEIGHT: h, WIDTH: w})
        feeds = {i.name: inputs[names.index(i.name)].numpy() for i in session.get_inputs()}
        got = session.run(None, feeds)[0]
    except Exception as exc:  # noqa: BLE001 - any runtime failure means: not size-free
        reraise_interruption(exc)
        raise OnnxExportError(f"the size-free graph does not run at {w}x{h} "
                              f"({type(exc).__name__}: {_first_line(exc)})") from exc
    scale = max(1.0, float(np.abs(expected).max()))
    if got.shape != expected.shape or not np.allclose(got, expected, rtol=1e-3,
                                                      atol=1e-3 * scale):
        diff = (float(np.abs(got - expected).max()) if got.shape == expected.shape
                else f"shape {got.shape} != {expected.shape}")
        raise OnnxExportError(f"the size-free graph differs from the network at {w}x{h} "
                              f"(max abs diff {diff}; a size is baked into the trace)")


SPEED_SESSION_MEMORY: Mapping[str, bool] = MappingProxyType({
    "enable_cpu_mem_arena": True, "enable_mem_pattern": False})
"""How a session on the CPU allocates (``SessionOptions`` attributes): ONNX Runtime's CPU arena
kept, its *memory pattern* off. With the pattern on (the default), a session plans one block
for all of a pass's intermediates, and at a large input that block, grown in the arena, is the
speed cell's peak. SSMA at 2048x1024 (the run's largest cell; fresh processes, the network
and its inputs included, AMD EPYC, ``avx512-vnni``, 2 threads): 4.14 GB with the defaults,
2.82 GB with the pattern off, 3.01 GB with the arena off, 2.67 GB with both off, 4.22 GB with
the arena grown by exactly what is asked (``kSameAsRequested``). The arena off slows a pass
(FEAGNet-V2 at 640x480 by 28 %, ESANet-R34 by 10-25 %); the pattern off does not, within the
timing's precision (docs/runner.md, "Timing memory"). The logits are bit-identical either way:
only where the intermediates live changes. Measured with ``benchmarks/ort_memory.py``."""


def session_memory(providers: Sequence[Any] | None = None) -> dict[str, bool]:
    """The memory settings :func:`session_for` gives a session on ``providers``:
    :data:`SPEED_SESSION_MEMORY` on the CPU, ONNX Runtime's own defaults on an accelerator
    (not measured there: its memory is not the host's)."""
    if providers and any(_provider_name(p) != "CPUExecutionProvider" for p in providers):
        return {}
    return dict(SPEED_SESSION_MEMORY)


def _provider_name(provider: Any) -> str:
    return str(provider[0] if isinstance(provider, (tuple, list)) else provider)


def session_for(path: str | os.PathLike[str], *, threads: int,
                free_dimensions: Mapping[str, int] | None = None,
                providers: list[Any] | None = None,
                memory: Mapping[str, bool] | None = None,
                config: Mapping[str, str] | None = None):
    """An ONNX Runtime session on ``path`` with all graph optimisations, ``threads``
    intra-op threads and the free dimensions pinned (a size-specialised session), on the CPU
    or on ``providers`` (:func:`evsmap.models.ort_providers.provider_chain`).

    ``memory`` (``SessionOptions`` flags) replaces :func:`session_memory`'s settings, and
    ``config`` adds session configuration entries; both are for measuring other settings
    (``benchmarks/ort_memory.py``)."""
    import onnxruntime as ort

    options = ort.SessionOptions()
    options.intra_op_num_threads = threads
    options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    options.log_severity_level = 3  # errors only
    for name, value in (free_dimensions or {}).items():
        options.add_free_dimension_override_by_name(name, int(value))
    settings = session_memory(providers) if memory is None else memory
    for name, flag in settings.items():
        setattr(options, name, bool(flag))
    for key, text in (config or {}).items():
        options.add_session_config_entry(key, text)
    return ort.InferenceSession(str(path), sess_options=options,
                                providers=providers or ["CPUExecutionProvider"])


def _write_json(path: Path, data: dict) -> None:
    with contextlib.suppress(OSError):
        from evsmap.fileio import atomic_write_text

        atomic_write_text(path, json.dumps(data))


def _first_line(exc: BaseException, limit: int = 160) -> str:
    text = str(exc).strip()
    line = text.splitlines()[0] if text else ""
    return line if len(line) <= limit else line[:limit - 3] + "..."
