"""Export a network to ONNX (one self-contained file) and cache the exports by weights."""

from __future__ import annotations

import contextlib
import hashlib
import io
import os
import re
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch

from evsmap.errors import EvsmapError
from evsmap.fileio import atomic_path
from evsmap.interrupt import reraise_interruption
from evsmap.models.module_utils import as_inputs, eval_mode

OPSET = 17
OUTPUT_NAMES = ("logits",)
CACHE_ENV = "EVSMAP_CACHE_DIR"


class OnnxExportError(EvsmapError):
    """A network that torch.onnx could not export, or whose export does not check."""


def default_cache_dir() -> Path:
    """``$EVSMAP_CACHE_DIR/onnx`` when set, else ``~/.cache/evsmap/onnx`` (the cache shared
    across runs, :mod:`evsmap.cache`)."""
    from evsmap.cache import cache_dir

    return cache_dir("onnx")


def export_onnx(
    module: torch.nn.Module,
    inputs: torch.Tensor | Sequence[torch.Tensor],
    input_names: Sequence[str],
    path: str | os.PathLike[str],
) -> Path:
    """Write ``module`` (in eval mode) as a single ONNX file at ``path`` and check it.

    Opset 17, fixed input shapes (those of ``inputs``), weights embedded (no external data
    files), output named ``logits``. Uses the TorchScript exporter (``dynamo=False``: exact
    opset 17 and fast); if that fails, tries the dynamo exporter before giving up.

    Raises:
        OnnxExportError: neither exporter succeeded, or the file fails ``onnx.checker``.
    """
    inputs = as_inputs(inputs)
    input_names = list(input_names)
    if len(input_names) != len(inputs):
        raise ValueError(f"{len(inputs)} inputs but {len(input_names)} input names")
    path = Path(path)
    name = type(module).__name__
    errors: list[str] = []
    with eval_mode(module), warnings.catch_warnings(), \
            contextlib.redirect_stdout(io.StringIO()):
        warnings.simplefilter("ignore")
        for dynamo in (False, True):
            extra: dict[str, Any] = {"external_data": False} if dynamo else {}
            try:
                torch.onnx.export(
                    module, inputs, str(path), input_names=input_names,
                    output_names=list(OUTPUT_NAMES), opset_version=OPSET, dynamo=dynamo,
                    verbose=False, **extra,
                )
                break
            except Exception as exc:  # any exporter failure is reported, not a crash
                reraise_interruption(exc)
                errors.append(f"{'dynamo' if dynamo else 'torchscript'} exporter: "
                              f"{type(exc).__name__}: {_first_line(exc)}")
        else:
            raise OnnxExportError(f"ONNX export of {name} failed ({'; '.join(errors)})")
    _check(path, name)
    return path


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else ""


def _check(path: Path, name: str) -> None:
    import onnx

    try:
        onnx.checker.check_model(str(path))
        model = onnx.load(str(path), load_external_data=False)
    except Exception as exc:
        raise OnnxExportError(f"ONNX export of {name} does not check: {_first_line(exc)}") \
            from exc
    external = [t.name for t in model.graph.initializer
                if t.data_location == onnx.TensorProto.EXTERNAL]
    if external:
        raise OnnxExportError(f"ONNX export of {name} stores {len(external)} tensors outside the "
                              f"file (e.g. {external[0]!r})")


def state_digest(module: torch.nn.Module) -> str:
    """SHA-256 of the module's state_dict: names, dtypes, shapes and the raw bytes."""
    h = hashlib.sha256()
    for key, value in module.state_dict().items():
        h.update(key.encode())
        if isinstance(value, torch.Tensor):
            t = value.detach().cpu().contiguous()
            h.update(f"{t.dtype}{tuple(t.shape)}".encode())
            h.update(t.reshape(-1).view(torch.uint8).numpy().tobytes())
        else:  # extra state
            h.update(repr(value).encode())
    return h.hexdigest()


def structure_digest(module: torch.nn.Module) -> str:
    """SHA-256 of what fixes a module's graph besides its weights: its ``repr``, the source
    code of every module class in it, and every submodule's plain attributes (numbers,
    strings, tuples: e.g. a pooling size computed from the input size the network was built
    for)."""
    import inspect

    h = hashlib.sha256(repr(module).encode())
    for cls in sorted({type(m) for m in module.modules()},
                      key=lambda c: f"{c.__module__}.{c.__qualname__}"):
        try:
            h.update(inspect.getsource(cls).encode())
        except (OSError, TypeError):  # no source (a compiled class): its name stands in
            h.update(f"{cls.__module__}.{cls.__qualname__}".encode())
    for name, sub in module.named_modules():
        plain = {k: v for k, v in vars(sub).items()
                 if not k.startswith("_") and isinstance(v, (bool, int, float, str, tuple))}
        h.update(f"{name}:{type(sub).__module__}.{type(sub).__qualname__}:"
                 f"{sorted(plain.items(), key=lambda kv: kv[0])!r}".encode())
    return h.hexdigest()


def cached_onnx(
    module: torch.nn.Module,
    inputs: torch.Tensor | Sequence[torch.Tensor],
    input_names: Sequence[str],
    *,
    key: str,
    cache_dir: str | os.PathLike[str] | None = None,
) -> Path:
    """Path of an ONNX export of ``module``, exported only when not already cached.

    The file name holds ``key`` (readable) and a hash of ``key``, the module's class, the input
    names, shapes and dtypes, the opset, the torch version, :func:`structure_digest` (the
    code of its module classes) and :func:`state_digest`, so new weights, changed code or
    another input size export again. The export goes to a temporary file in the
    cache folder and is renamed into place, so a partial file is never picked up.
    """
    inputs = as_inputs(inputs)
    cache = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    h = hashlib.sha256()
    for part in (key, f"{type(module).__module__}.{type(module).__qualname__}",
                 ",".join(input_names),
                 ";".join(f"{t.dtype}{tuple(t.shape)}" for t in inputs),
                 str(OPSET), torch.__version__, structure_digest(module),
                 state_digest(module)):
        h.update(part.encode())
        h.update(b"\0")
    stem = re.sub(r"[^A-Za-z0-9._-]+", "_", key).strip("._") or "model"
    path = cache / f"{stem[:64]}-{h.hexdigest()[:20]}.onnx"
    if path.is_file():
        return path
    try:
        cache.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OnnxExportError(f"cannot create ONNX cache folder {cache}: {exc}") from exc
    with atomic_path(path, suffix=".onnx") as tmp:
        export_onnx(module, inputs, input_names, tmp)
    return path
