"""Cells that measure a network (Tables I-III): parameters and FLOPs (fvcore), speed
(torch or ONNX Runtime, with the contention check and one retry), and mIoU on a dataset's split
through the measurement engine."""

from __future__ import annotations

import os
import time
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from evsmap.errors import EvsmapError, InvalidDataError
from evsmap.interfaces import Segmenter
from evsmap.runner.cell_base import (
    RETRY_PAUSE_S,
    STRICT_PAUSE_S,
    base_fields,
    column_quantities,
    now,
)
from evsmap.runner.context import RunContext
from evsmap.runner.records import CellRecord
from evsmap.tables.schema import CellSpec, Component

if TYPE_CHECKING:
    import torch

    from evsmap.measure.speed import SpeedRecord
    from evsmap.metrics import SegmentationResult


def cell_network(spec: CellSpec) -> Component:
    """The network a complexity, speed or accuracy cell measures.

    Raises:
        EvsmapError: the cell names no segmenter (the tables give every such cell one).
    """
    if spec.segmenter is None:
        raise EvsmapError(f"{spec.key}: the cell names no segmenter")
    return spec.segmenter


def build_segmenter(component: Component, *, input_size: Sequence[int] | None = None,
                    backend: str | None = None, weights: str | None = None) -> Segmenter:
    """The segmenter of ``component`` (an untrained network's random weights drawn from
    :data:`~evsmap.segmenters.create.RANDOM_INIT_SEED`: the same every run, so ONNX exports are
    reused)."""
    from evsmap.registry import SEGMENTERS
    from evsmap.segmenters.create import RANDOM_INIT_SEED, create_segmenter

    config = dict(component.config)
    takes = SEGMENTERS.get(component.name).takes
    if input_size is not None and takes.input_size:
        config["input_size"] = tuple(input_size)
    if backend is not None and takes.backend:
        config["backend"] = backend
    if weights is not None:
        config["weights"] = weights
    segmenter: Segmenter = create_segmenter(component.name, init_seed=RANDOM_INIT_SEED, **config)
    return segmenter


def _network(segmenter: Segmenter) -> torch.nn.Module:
    """The torch module of a network segmenter.

    Raises:
        InvalidDataError: the segmenter is not a network.
    """
    module = segmenter.module
    if module is None:
        raise InvalidDataError(f"{type(segmenter).__name__} is not a network: it has nothing to "
                               f"measure")
    return module


def _size(spec: CellSpec, segmenter: Segmenter) -> tuple[int, int]:
    size = spec.input_size or segmenter.default_size
    if size is None:
        raise InvalidDataError(f"{spec.key}: no input size (the cell names none and "
                               f"{type(segmenter).__name__} has no default)")
    h, w = size
    return h, w


def run_complexity(spec: CellSpec, ctx: RunContext) -> CellRecord:
    from evsmap.measure.complexity import cached_complexity, count_parameters

    segmenter = build_segmenter(cell_network(spec))
    module = _network(segmenter)
    quantities = column_quantities(spec)
    if set(quantities.values()) == {"params"}:  # no input size in a parameter count
        params = count_parameters(module)
        return CellRecord(**base_fields(spec), status="ok",
                          values={col: float(params) for col in quantities},
                          notes=["every parameter of the network, training-only heads included "
                                 "where it has them; the count does not depend on the input "
                                 "size"], details={"params": params})
    h, w = _size(spec, segmenter)
    rec = cached_complexity(module, segmenter.example_inputs(h, w))
    values = {col: float(rec.params if q == "params" else rec.flops)
              for col, q in quantities.items()}
    notes = [f"fvcore at {w}x{h} (1 MAC = 1 FLOP, as fvcore and the paper's lineage count)"]
    if rec.uncounted_ops and "flops" in quantities.values():
        notes.append("operators fvcore does not count: " + ", ".join(sorted(rec.uncounted_ops)))
    return CellRecord(**base_fields(spec), status="ok", values=values, notes=notes,
                      details=rec.as_dict())


def run_roofline(ctx: RunContext) -> float:
    """The fp32 matmul roofline of this machine at the run's thread count, or of the run's GPU
    (G MAC/s): measured by the run's first speed cell, read from ``<run>/cache/roofline.json``
    by the others (one machine fact per run, not re-measured per cell)."""
    import json

    from evsmap.fileio import atomic_write_text
    from evsmap.measure.speed import roofline_gmacs
    from evsmap.models.module_utils import torch_threads

    path = Path(ctx.out) / "cache" / "roofline.json"
    try:
        known = json.loads(path.read_text())
    except (OSError, ValueError):
        known = {}
    key = str(ctx.threads) if ctx.device == "cpu" else ctx.device
    if key in known:
        return float(known[key])
    with torch_threads(ctx.threads):
        value = roofline_gmacs(device=ctx.device)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(path, json.dumps({**known, key: value}))
    return value


def run_speed(spec: CellSpec, ctx: RunContext) -> CellRecord:
    from evsmap.measure.complexity import cached_complexity
    from evsmap.measure.contention import (
        HOST_SLOWDOWN_NOTE,
        CalibrationLog,
        machine_log_path,
        retry_can_help,
        severity,
    )
    from evsmap.measure.speed import measure_speed
    from evsmap.measure.speed_backends import make_backend

    network = cell_network(spec)
    segmenter = build_segmenter(network, input_size=spec.input_size)
    h, w = _size(spec, segmenter)
    inputs = segmenter.example_inputs(h, w)
    module = _network(segmenter)
    macs = cached_complexity(module, inputs).flops
    export = None
    if ctx.speed_backend == "onnxruntime":
        # one size-free export per network, cached across runs (evsmap.models.speed_export)
        from evsmap.models.speed_export import session_memory, speed_export

        export = speed_export(module, inputs, segmenter.input_names, key=network.spec)
    log = CalibrationLog(Path(ctx.out) / "cache" / "calibration.json",
                         machine_path=machine_log_path())
    policy = ctx.timing_policy()
    roofline = run_roofline(ctx)
    if export is not None:  # what the export and the counts left behind is not timed with
        import gc

        from evsmap.measure.memory import trim_heap

        # the session holds the weights: the module's copy is freed (RDFNet-R101: 1.43 GB
        # held twice made its cell peak at 4.01 GB); its class and counts are all that is read
        module.to("meta")
        gc.collect()
        trim_heap()

    backend = make_backend(ctx.speed_backend, onnx=None if export is None else {
        "onnx_path": export.path, "free_dimensions": export.free_dimensions(h, w),
        "input_names": tuple(segmenter.input_names), "key": network.spec})

    def measure() -> SpeedRecord:
        # on a GPU the timing definition's one host thread (evsmap.measure.pass_timing)
        return measure_speed(module, inputs, backend=backend,
                             threads=ctx.threads if ctx.device == "cpu" else None, macs=macs,
                             calibration_log=log, policy=policy, roofline=roofline,
                             device=ctx.device)

    rec = measure()
    retried = ctx.strict_timing or retry_can_help(rec.contention)
    if rec.contention.get("contended") and retried:
        # one more try once the other work may have passed; keep the less contended
        time.sleep(STRICT_PAUSE_S if ctx.strict_timing else RETRY_PAUSE_S)
        again = measure()
        if severity(again.contention) < severity(rec.contention):
            rec = again
        if ctx.strict_timing and rec.contention.get("contended"):
            return CellRecord(**base_fields(spec), status="na", needs=["an idle machine"],
                              reason=f"n/a - --strict-timing: the machine was busy "
                                     f"({rec.flag}); rerun when it is idle",
                              details=rec.as_dict(), started=now())
    values = {col: float(rec.fps_median) for col in spec.metrics}
    where = (f"on the CPU ({rec.threads} threads, {rec.cpu})" if not rec.gpu else
             f"on {rec.device} ({rec.gpu['gpu']}, CUDA events, {rec.threads} host thread"
             f"{'s' if rec.threads != 1 else ''}, after a warm-up of "
             f"{(rec.settle or {}).get('passes', 0)} passes until the speed settled; "
             f"{busy_text(rec.busy)})")
    notes = [f"{ctx.speed_backend} {where}, {w}x{h}, "
             f"median of {rec.runs} passes after {rec.warmup} warm-up, "
             f"{precision_text(rec.as_dict())}; untrained weights (speed does not depend on "
             f"them)"]
    from evsmap.segmenters.create import RANDOM_INIT_SEED, weights_fields

    details = {**rec.as_dict(), **weights_fields(segmenter, RANDOM_INIT_SEED)}
    if export is not None:
        details["export"] = {"path": export.path.name, "size_free": export.size_free,
                             "export_s": export.export_s, "cached": export.export_s is None,
                             "note": export.note}
        # how the session allocates ({}: ONNX Runtime's defaults; SPEED_SESSION_MEMORY)
        details["ort_memory"] = session_memory() if ctx.device == "cpu" else {}
        if export.note:
            notes.append(export.note)
    if rec.flag:
        notes.append(f"timing flagged - {rec.flag}")
        if rec.contention.get("contended") and not retried:
            notes.append(HOST_SLOWDOWN_NOTE)
        details["timing_flag"] = rec.flag
    return CellRecord(**base_fields(spec), status="ok", values=values, notes=notes,
                      details=details)


def busy_text(busy: dict[str, Any]) -> str:
    """Where a GPU pass's time went, in words (:class:`evsmap.measure.pass_timing.
    DeviceBusy`'s fields)."""
    if busy.get("busy_share") is None:
        return f"GPU busy share not measured: {busy.get('why') or 'unknown'}"
    return (f"GPU busy {100 * busy['busy_share']:.0f} % of the pass "
            f"({busy['kernel_ms']:.2f} ms of kernels): {busy['bound']}-bound")


def precision_text(details: dict[str, Any]) -> str:
    """How precise a speed cell's median is, in words: "+-1.2 % (95 % CI), 12 passes" and,
    when it stopped on its budget, that it did."""
    rel, stopped = details.get("rel_ci"), details.get("stopped")
    if rel is None:
        return "precision not measured (timed in rounds)"
    policy = details.get("policy") or {}
    level = policy.get("confidence", 0.95)
    text = f"median +-{rel * 100:.1f} % ({level:.0%} CI)"
    if stopped == "budget":
        text += (f", stopped on its {policy.get('budget_s', 0):g} s budget before "
                 f"+-{policy.get('target_rel_ci', 0) * 100:g} %")
    elif stopped == "max_runs":
        text += f", stopped after its {policy.get('max_runs')} passes at most"
    return text


def run_accuracy(spec: CellSpec, ctx: RunContext) -> CellRecord:
    dataset = spec.datasets[0]
    path = ctx.dataset_path(dataset)
    network = cell_network(spec)
    choice = ctx.weights_choice(network.spec, dataset)
    if path is None or choice is None:  # guarded by the caller's needs check
        raise EvsmapError(f"{spec.key}: dataset or weights missing")
    split = spec.split or "test"
    result, frames = dataset_miou(network, dataset, path, split, choice.path,
                                  input_size=spec.input_size, backend=ctx.speed_backend,
                                  limit=10 if ctx.quick else None)
    values = {col: float(result.miou) for col in spec.metrics}
    notes = [f"{dataset} {split} split, {frames} images, weights {choice.file}", choice.note()]
    return CellRecord(**base_fields(spec), status="ok", values=values, notes=notes,
                      details=result.as_dict())


def dataset_miou(component: Component, dataset: str, path: str | os.PathLike[str], split: str,
                 weights: str | os.PathLike[str], *, input_size: Sequence[int] | None = None,
                 backend: str | None = None, limit: int | None = None
                 ) -> tuple[SegmentationResult, int]:
    """``(result, frames)``: one dataset-level confusion matrix of ``component`` with
    ``weights`` over ``dataset``'s ``split`` (:class:`~evsmap.metrics.ConfusionMatrix`'s
    result; its ``miou`` over the classes present in ground truth or prediction)."""
    segmenter = build_segmenter(component, input_size=input_size, backend=backend,
                                weights=str(weights))
    return score_segmenter(segmenter, dataset, path, split, input_size=input_size,
                           limit=limit, what=component.spec)


def score_segmenter(segmenter: Segmenter, dataset: str, path: str | os.PathLike[str],
                    split: str, *, input_size: Sequence[int] | None = None,
                    limit: int | None = None, what: str | None = None
                    ) -> tuple[SegmentationResult, int]:
    """:func:`dataset_miou` for a segmenter already built (e.g. calibrated to int8)."""
    from evsmap.datasets.lookup import dataset_classes
    from evsmap.measure.engine import run_segmentation
    from evsmap.measure.evaluators import ConfusionEvaluator
    from evsmap.registry import READERS

    config: dict[str, Any] = {"path": str(path), "split": split}
    if input_size and READERS.get(dataset).takes.resolution:
        config["resolution"] = f"{input_size[1]}x{input_size[0]}"
    if limit is not None:
        config["limit"] = limit
    sequence = READERS.create(dataset, **config)
    n_data, names = dataset_classes(sequence)
    if n_data is not None and n_data != segmenter.num_classes:
        raise EvsmapError(f"{what or type(segmenter).__name__} predicts "
                          f"{segmenter.num_classes} classes, {dataset} has {n_data}")
    scored = run_segmentation(sequence, segmenter, evaluators=[
        ConfusionEvaluator(num_classes=segmenter.num_classes, class_names=names,
                           source=sequence.name)])
    result: SegmentationResult = scored.results["confusion"]
    return result, scored.frames
