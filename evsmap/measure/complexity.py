"""Parameter and FLOP counts of a network (the paper's Tables I-III, "Params" and "FLOPs")."""

from __future__ import annotations

import logging
import warnings
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import torch

from evsmap.models.module_utils import as_inputs, eval_mode, image_size

# fvcore reports skipped operators through these loggers; we record them instead.
_FVCORE_LOGGERS = ("fvcore", "fvcore.nn.jit_analysis")


@dataclass(frozen=True)
class ComplexityRecord:
    """Size and cost of one forward pass.

    Attributes:
        params: number of parameters (all of them, trainable or not; shared ones once).
        flops: fvcore's total for one forward pass in eval mode. fvcore counts one
            multiply-accumulate (MAC) as one flop, so this is a MAC count, as in the paper.
        conv_macs: the part of ``flops`` from convolutions (fvcore's ``"conv"`` operator).
        by_operator: fvcore's count per operator kind (``"conv"``, ``"batchnorm"``, ...).
        uncounted_ops: operators fvcore has no formula for and skipped (e.g.
            ``"aten::sigmoid"``), with how many times each was called; their cost is not in
            ``flops``.
        height, width: input image size the counts are for.
    """

    params: int
    flops: int
    conv_macs: int
    by_operator: dict[str, int] = field(default_factory=dict)
    uncounted_ops: dict[str, int] = field(default_factory=dict)
    height: int = 0
    width: int = 0

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


def count_parameters(module: torch.nn.Module) -> int:
    """All parameters of ``module`` (shared ones counted once)."""
    return sum(p.numel() for p in module.parameters())


def measure_complexity(
    module: torch.nn.Module, inputs: torch.Tensor | Sequence[torch.Tensor]
) -> ComplexityRecord:
    """Count parameters and FLOPs of ``module(*inputs)`` with fvcore.

    The module is traced in eval mode (its modes are restored afterwards) without gradients.
    fvcore counts one multiply-accumulate as one flop, so ``flops`` is a MAC count. Operators
    fvcore cannot count are not dropped silently: they are listed in ``uncounted_ops``. fvcore's
    own warnings and log messages are silenced because the record carries them.
    """
    with warnings.catch_warnings():  # fvcore's imports use the deprecated torch.jit.script
        warnings.simplefilter("ignore")
        from fvcore.nn import FlopCountAnalysis

    inputs = as_inputs(inputs)
    height, width = image_size(inputs)
    loggers = [logging.getLogger(name) for name in _FVCORE_LOGGERS]
    levels = [lg.level for lg in loggers]
    try:
        for lg in loggers:
            lg.setLevel(logging.ERROR)
        with eval_mode(module), torch.no_grad(), warnings.catch_warnings():
            warnings.simplefilter("ignore")
            analysis = (
                FlopCountAnalysis(module, inputs)
                .unsupported_ops_warnings(False)
                .uncalled_modules_warnings(False)
                .tracer_warnings("none")
            )
            total = int(analysis.total())
            by_operator = {str(k): int(v) for k, v in analysis.by_operator().items()}
            uncounted = {str(k): int(v) for k, v in analysis.unsupported_ops().items()}
    finally:
        for lg, level in zip(loggers, levels, strict=True):
            lg.setLevel(level)
    return ComplexityRecord(
        params=count_parameters(module),
        flops=total,
        conv_macs=by_operator.get("conv", 0),
        by_operator=dict(sorted(by_operator.items())),
        uncounted_ops=dict(sorted(uncounted.items())),
        height=height,
        width=width,
    )


def cached_complexity(module: torch.nn.Module, inputs: torch.Tensor | Sequence[torch.Tensor]
                      ) -> ComplexityRecord:
    """:func:`measure_complexity`, stored in the cache shared across runs
    (``<cache>/complexity``) under the module's structure and code, the inputs' shapes and
    dtypes, and the torch and fvcore versions: the counts do not depend on the weights, so a
    speed cell reuses what the complexity cell of the same network and size counted."""
    import hashlib
    import json
    from importlib import metadata

    from evsmap.cache import cache_dir
    from evsmap.fileio import atomic_write_text
    from evsmap.models.onnx_export import structure_digest

    inputs = as_inputs(inputs)
    h = hashlib.sha256()
    for part in (structure_digest(module), ";".join(f"{t.dtype}{tuple(t.shape)}" for t in inputs),
                 torch.__version__, metadata.version("fvcore")):
        h.update(part.encode())
        h.update(b"\0")
    path = cache_dir("complexity") / f"{h.hexdigest()[:24]}.json"
    try:
        return ComplexityRecord(**json.loads(path.read_text()))
    except (OSError, ValueError, TypeError):
        pass
    record = measure_complexity(module, inputs)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(path, json.dumps(record.as_dict()))
    except OSError:  # a read-only cache: counted again next time
        pass
    return record
