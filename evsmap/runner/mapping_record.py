"""A mapping run's record (:func:`mapping_record`): the sequence mapped through the measurement
engine with its labels (:mod:`evsmap.runner.mapping_labels`), each update timed, the map's files,
sizes and 3D quality, the machine's load around it, and the artifacts the report's views show."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from evsmap.data import SemanticObservation
from evsmap.data import Sequence as FrameSequence
from evsmap.interfaces import MapUpdater
from evsmap.measure.engine import MappingPass, run_mapping
from evsmap.measure.mapping import MappingRecord
from evsmap.runner.cell_base import now
from evsmap.runner.context import RunContext
from evsmap.runner.mapping_labels import LabelCaches, Labels, options_text, run_labels
from evsmap.runner.mapping_plan import (
    SYNTHETIC_SEQUENCES,
    MappingRun,
    missing_dataset,
    open_mapping_sequence,
    synthetic_options,
)
from evsmap.runner.records import CellRecord, needs_text


def mapping_record(run: MappingRun, ctx: RunContext) -> CellRecord:
    """Map ``run.sequence`` with ``run``'s system; time each update, add the segmentation time
    per frame, measure the map file and (where the sequence has 3D ground truth: the synthetic
    room, a ScanNet scene) its 3D quality."""
    from evsmap.measure.contention import CalibrationLog, Probe, contention, machine_log_path

    dataset = missing_dataset(ctx, run.sequence)
    if dataset is not None:
        need = f"dataset:{dataset}"
        return CellRecord(**run.base_fields(), status="na", needs=[need],
                          reason=needs_text([need]), started=now())
    sequence = open_mapping_sequence(ctx, run.sequence)
    n = len(sequence) if ctx.frames is None else min(ctx.frames, len(sequence))
    indices = list(range(n))
    caches = LabelCaches(ctx, sequence)
    before = Probe.take()  # the machine around the timed part (segmentation and update)
    labels = run_labels(run, ctx, caches, sequence, indices)
    if isinstance(labels, CellRecord):
        return labels
    mapped = _map(run, ctx, sequence, indices, labels.observations)
    machine = contention(before, Probe.take(),
                         CalibrationLog(Path(ctx.out) / "cache" / "calibration.json",
                                        machine_path=machine_log_path()))
    record = MappingRecord.from_run(
        mapped, updater=run.updater.spec, segmenter=None if run.segmenter is None
        else run.segmenter.spec, segment_ms=labels.segment_ms)
    values, details = _values_and_details(record, mapped, labels)
    if run.segmenter is not None:  # which labels the semantic figures used
        details["labels_from"] = labels.labels_from
        if labels.origin:
            details["labels"] = labels.origin
    notes = labels.notes + [
        f"{n} frames of {sequence.name} at {run.resolution:g} m; rates are medians over "
        f"frames (update only; segmentation + update = the median segmentation time + the "
        f"median update time)"]
    _add_contention(machine, details, notes)
    truth = _ground_truth(run, ctx, sequence) if mapped.updater.has_leaf_map else None
    if truth is not None:
        _add_quality(truth, mapped.updater, values, details)
    if run.sequence in SYNTHETIC_SEQUENCES and mapped.updater.has_leaf_map and run.views:
        _save_artifacts(run, ctx, mapped.updater, sequence, indices, labels)
    return CellRecord(**run.base_fields(), status="ok", values=values, notes=notes,
                      details=details)


def _map(run: MappingRun, ctx: RunContext, sequence: FrameSequence, indices: list[int],
         observations: list[SemanticObservation] | None) -> MappingPass:
    """The timed mapping pass; the map's own memory is measured from before the updater is made
    to its files (the observations were computed beforehand)."""
    from evsmap.measure.evaluators import MapFiles, MapStatistics, PrunedShare
    from evsmap.measure.growth import MapGrowth, growth_every, growth_points
    from evsmap.registry import UPDATERS

    n = len(indices)
    return run_mapping(
        sequence, lambda: UPDATERS.create(run.updater.name, resolution=run.resolution,
                                          **run.updater.config),
        observations=observations, indices=indices,
        evaluators=[MapStatistics(), MapFiles(), PrunedShare()],
        growth=MapGrowth(every=growth_every(n, growth_points(n, quick=ctx.quick))))


def _values_and_details(record: MappingRecord, mapped: MappingPass,
                        labels: Labels) -> tuple[dict[str, float], dict[str, Any]]:
    """The cell record's ``values`` (:meth:`MappingRecord.values`, with the share of pruned
    leaves) and ``details`` (per-frame times, counts, front end, growth, precision)."""
    values = record.values()
    share = mapped.results["pruned_share"]  # on the finished map's one tree (PrunedShare)
    if share is not None:
        values["pruned_share"] = float(share)
    details: dict[str, Any] = {
        "update_ms": record.update_ms, "segment_ms": record.segment_ms,
        "nodes": record.nodes, "leaves": record.leaves, "sequence_name": record.sequence,
        **values, "front_end": record.front_end, "growth": mapped.results["growth"]}
    if labels.timing is not None:
        details["segment_timing"] = {k: labels.timing[k] for k in
                                     ("rel_ci", "stopped", "warmup", "policy")
                                     if k in labels.timing}
    details["rel_ci"] = segment_update_precision(record.update_ms, record.segment_ms)
    return values, details


def _add_contention(machine: dict[str, Any], details: dict[str, Any], notes: list[str]) -> None:
    """The machine's load around the timed part, and a flag where it was contended."""
    details["contention"] = machine
    details["calibration_gmacs"] = math.sqrt(machine["before"]["calibration_gmacs"]
                                             * machine["after"]["calibration_gmacs"])
    if machine["contended"]:
        from evsmap.measure.contention import describe

        flag = describe(machine) + " around this mapping run"
        details["timing_flag"] = flag
        notes.append(f"timing flagged - {flag}")


def _ground_truth(run: MappingRun, ctx: RunContext, sequence: FrameSequence) -> Any:
    """The scene's voxels at the run's voxel size: the synthetic room's (rebuilt from its
    options; the sequence mapped is its rendering read back), a ScanNet scene's labelled mesh;
    None for a sequence without 3D ground truth."""
    if run.sequence in SYNTHETIC_SEQUENCES:
        from evsmap.synth.cached import cached_ground_truth

        return cached_ground_truth(synthetic_options(ctx, run.sequence), run.resolution)
    return sequence.ground_truth(run.resolution) if sequence.has_ground_truth else None


def _add_quality(truth: Any, updater: MapUpdater, values: dict[str, float],
                 details: dict[str, Any]) -> None:
    """The map's 3D quality against ``truth`` (outside the memory scope): in
    ``details["quality"]``, its finite fractions in ``values``."""
    from evsmap.measure.evaluators import MapQualityEvaluator

    quality = MapQualityEvaluator(truth).evaluate(updater)
    q = quality.as_dict() if quality is not None else {}
    details["quality"] = q
    for name in ("precision", "recall", "semantic_accuracy", "semantic_accuracy_all",
                 "map_miou", "scene_miou"):
        if q.get(name) is not None and np.isfinite(q[name]):
            values[name] = float(q[name])


def _save_artifacts(run: MappingRun, ctx: RunContext, updater: MapUpdater,
                    sequence: FrameSequence,
                    indices: list[int], labels: Labels) -> None:
    """The map's points (for the views of Table IV's maps) and one segmented frame."""
    if run.resolution == ctx.resolution:  # the views show Table IV's maps
        _save_map_artifact(updater, run, ctx)
    if labels.observations is not None:
        middle = len(indices) // 2
        _save_segmentation_artifact(sequence, indices[middle], labels.observations[middle],
                                    run, ctx, labels)


def _save_map_artifact(updater: MapUpdater, run: MappingRun, ctx: RunContext) -> None:
    from evsmap.updaters.export import occupied_points

    centres, rgb, labels = occupied_points(updater)
    folder = Path(ctx.out) / "artifacts"
    folder.mkdir(parents=True, exist_ok=True)
    n = len(centres)
    np.savez_compressed(
        folder / f"map-{run.row}-{run.sequence}.npz", centres=centres.astype(np.float32),
        labels=labels if labels is not None else np.full(n, -1, dtype=np.int16),
        colors=rgb if rgb is not None else np.zeros((n, 3), dtype=np.uint8),
        resolution=np.float64(run.resolution))


def _save_segmentation_artifact(sequence: FrameSequence, index: int,
                                observation: SemanticObservation, run: MappingRun,
                                ctx: RunContext, labels: Labels) -> None:
    folder = Path(ctx.out) / "artifacts"
    path = folder / f"seg-{labels.source}-{run.sequence}.npz"
    if path.exists():
        return
    folder.mkdir(parents=True, exist_ok=True)
    frame = sequence.frame(index)
    title = (f"{labels.labels_from} on {sequence.name} frame {index}"
             + (f" ({options_text(ctx.oracle)})" if labels.source == "oracle" else ""))
    arrays: dict[str, Any] = {"rgb": frame.rgb, "gt": frame.labels, "pred": observation.argmax,
                              "title": np.str_(title)}
    np.savez_compressed(path, **arrays)


def segment_update_precision(update_ms: list[float], segment_ms: list[float]) -> float | None:
    """The precision of ``segment_update_hz`` (1000 / (median update + median segmentation)):
    each median's 95 % bootstrap interval, their half-widths added, over the sum."""
    from evsmap.measure.timing_policy import median_ci, relative_half_width, sum_precision

    parts = []
    for times in (update_ms, segment_ms):
        if times:
            median, low, high = median_ci(times)
            parts.append((median, relative_half_width(median, low, high)))
    return sum_precision(parts) if parts else None
