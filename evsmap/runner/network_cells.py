"""Cells that measure a network (Tables I-III): parameters and FLOPs (fvcore), speed
(torch or ONNX Runtime, with the contention check and one retry), and mIoU on a dataset's split
through the measurement engine."""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any

from evsmap.errors import EvsmapError
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


def build_segmenter(component: Component, *, input_size=None, backend: str | None = None,
                    weights: str | None = None):
    """The segmenter of ``component`` (seeded: untrained networks get the same weights every
    run, so ONNX exports are reused)."""
    import torch

    from evsmap.registry import SEGMENTERS

    config = dict(component.config)
    params = SEGMENTERS.get(component.name).parameters()
    if input_size is not None and "input_size" in params:
        config["input_size"] = tuple(input_size)
    if backend is not None and "backend" in params:
        config["backend"] = backend
    if weights is not None:
        config["weights"] = weights
    torch.manual_seed(0)
    return SEGMENTERS.create(component.name, **config)


def _size(spec: CellSpec, segmenter) -> tuple[int, int]:
    return tuple(spec.input_size) if spec.input_size else tuple(segmenter.default_size)


def run_complexity(spec: CellSpec, ctx: RunContext) -> CellRecord:
    from evsmap.measure.complexity import measure_complexity

    segmenter = build_segmenter(spec.segmenter)
    h, w = _size(spec, segmenter)
    rec = measure_complexity(segmenter.module, segmenter.example_inputs(h, w))
    quantities = column_quantities(spec)
    values = {col: float(rec.params if q == "params" else rec.flops)
              for col, q in quantities.items()}
    if set(quantities.values()) == {"params"}:  # no input size in a parameter count
        notes = ["every parameter of the network, training-only heads included where it has them; "
                 "the count does not depend on the input size"]
    else:
        notes = [f"fvcore at {w}x{h} (1 MAC = 1 FLOP, as fvcore and the paper's lineage "
                 f"count)"]
    if rec.uncounted_ops and "flops" in quantities.values():
        notes.append("operators fvcore does not count: " + ", ".join(sorted(rec.uncounted_ops)))
    return CellRecord(**base_fields(spec), status="ok", values=values, notes=notes,
                      details=rec.as_dict())


def run_speed(spec: CellSpec, ctx: RunContext) -> CellRecord:
    from evsmap.measure.complexity import measure_complexity
    from evsmap.measure.speed import measure_speed

    segmenter = build_segmenter(spec.segmenter, input_size=spec.input_size)
    h, w = _size(spec, segmenter)
    inputs = segmenter.example_inputs(h, w)
    macs = measure_complexity(segmenter.module, inputs).flops
    from evsmap.measure.contention import CalibrationLog, machine_log_path
    from evsmap.models.onnx_export import default_cache_dir

    # ONNX exports: the cache shared across runs (content-addressed by network and weights)
    cache = default_cache_dir() if ctx.speed_backend == "onnxruntime" else None
    log = CalibrationLog(Path(ctx.out) / "cache" / "calibration.json",
                         machine_path=machine_log_path())

    def measure():
        return measure_speed(segmenter.module, inputs, backend=ctx.speed_backend,
                             runs=ctx.speed_runs, warmup=ctx.speed_warmup, threads=ctx.threads,
                             macs=macs, input_names=segmenter.input_names,
                             key=spec.segmenter.spec, cache_dir=cache,
                             max_rounds=ctx.max_rounds, stable_rel_iqr=ctx.stable_rel_iqr,
                             calibration_log=log)

    rec = measure()
    if rec.contention.get("contended"):
        # one more try once the other work may have passed; keep the less contended
        time.sleep(STRICT_PAUSE_S if ctx.strict_timing else RETRY_PAUSE_S)
        again = measure()
        from evsmap.measure.contention import severity

        if severity(again.contention) < severity(rec.contention):
            rec = again
        if ctx.strict_timing and rec.contention.get("contended"):
            return CellRecord(**base_fields(spec), status="na", needs=["an idle machine"],
                              reason=f"n/a - --strict-timing: the machine was busy "
                                     f"({rec.flag}); rerun when it is idle",
                              details=rec.as_dict(), started=now())
    values = {col: float(rec.fps_median) for col in spec.metrics}
    notes = [f"{ctx.speed_backend} on the CPU ({rec.threads} threads, {rec.cpu}), {w}x{h}, "
             f"median of {rec.runs} runs after {rec.warmup} warm-up"
             + (f" (round {rec.rounds} of at most {ctx.max_rounds}: the first with IQR/median "
                f"<= {ctx.stable_rel_iqr:g})" if rec.rounds > 1 and rec.stable else "")
             + "; untrained weights (speed does not depend on them)"]
    details = rec.as_dict()
    if rec.flag:
        notes.append(f"timing flagged - {rec.flag}")
        details["timing_flag"] = rec.flag
    return CellRecord(**base_fields(spec), status="ok", values=values, notes=notes,
                      details=details)


def run_accuracy(spec: CellSpec, ctx: RunContext) -> CellRecord:
    dataset = spec.datasets[0]
    path = ctx.dataset_path(dataset)
    choice = ctx.weights_choice(spec.segmenter.spec, dataset)
    if path is None or choice is None:  # guarded by the caller's needs check
        raise EvsmapError(f"{spec.key}: dataset or weights missing")
    split = spec.split or "test"
    result, frames = dataset_miou(spec.segmenter, dataset, path, split, choice.path,
                                  input_size=spec.input_size, backend=ctx.speed_backend,
                                  limit=10 if ctx.quick else None)
    values = {col: float(result.miou) for col in spec.metrics}
    notes = [f"{dataset} {split} split, {frames} images, weights {choice.file}", choice.note()]
    return CellRecord(**base_fields(spec), status="ok", values=values, notes=notes,
                      details=result.as_dict())


def dataset_miou(component: Component, dataset: str, path: str | os.PathLike[str], split: str,
                 weights: str | os.PathLike[str], *, input_size=None,
                 backend: str | None = None, limit: int | None = None):
    """``(result, frames)``: one dataset-level confusion matrix of ``component`` with
    ``weights`` over ``dataset``'s ``split`` (:class:`~evsmap.metrics.ConfusionMatrix`'s
    result; its ``miou`` over the classes present in ground truth or prediction)."""
    segmenter = build_segmenter(component, input_size=input_size, backend=backend,
                                weights=str(weights))
    return score_segmenter(segmenter, dataset, path, split, input_size=input_size,
                           limit=limit, what=component.spec)


def score_segmenter(segmenter, dataset: str, path: str | os.PathLike[str], split: str, *,
                    input_size=None, limit: int | None = None, what: str | None = None):
    """:func:`dataset_miou` for a segmenter already built (e.g. calibrated to int8)."""
    from evsmap.datasets.lookup import dataset_classes
    from evsmap.measure.engine import run_segmentation
    from evsmap.measure.evaluators import ConfusionEvaluator
    from evsmap.registry import READERS

    config: dict[str, Any] = {"path": str(path), "split": split}
    if input_size and "resolution" in READERS.get(dataset).parameters():
        config["resolution"] = f"{input_size[1]}x{input_size[0]}"
    if limit is not None:
        config["limit"] = limit
    sequence = READERS.create(dataset, **config)
    n_data, names = dataset_classes(sequence)
    if n_data is not None and n_data != segmenter.num_classes:
        raise EvsmapError(f"{what or segmenter.name} predicts {segmenter.num_classes} classes, "
                          f"{dataset} has {n_data}")
    scored = run_segmentation(sequence, segmenter, evaluators=[
        ConfusionEvaluator(num_classes=segmenter.num_classes, class_names=names,
                           source=sequence.name)])
    return scored.results["confusion"], scored.frames
