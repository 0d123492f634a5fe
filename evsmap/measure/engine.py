"""The measurement engine: the two timed loops every figure of evsmap comes from.

:func:`run_segmentation` reads frames and runs a segmenter over them; :func:`run_mapping` reads
frames, segments them (or takes observations computed beforehand) and integrates them into a
map updater. Both time each stage of each frame with ``time.perf_counter`` and hand every frame
to evaluator objects (:mod:`evsmap.measure.evaluators`, in the spirit of detectron2's
``DatasetEvaluator`` and ``inference_on_dataset``): a confusion matrix, the observations kept for
a cache, the map's files and statistics, its 3D quality. The command line (``evsmap eval``,
``evsmap map``), the matrix runner (Tables I-IV), the segmentation cache, the regression gates
and the benchmarks all call these two functions, so a rate in a report, a gate and a benchmark
is timed the same way.

What is timed, per frame, in milliseconds (``stages_ms``):

``read``          the reader's ``Sequence.frame`` (decoding, undistortion, pose lookup)
``predict``       the segmenter's ``predict`` (a network: also its ``last_timings`` stages
                  ``preprocess`` / ``network`` / ``postprocess``; the oracle's time is its own
                  stage, ``oracle``, and is not a segmentation time)
``update``        the updater's ``integrate``

Warm-up frames (``warmup``: the segmenter's, and one update into a scratch copy of the empty map)
run before the loop and are not recorded. Evaluators run outside
the timed spans.
"""

from __future__ import annotations

import copy
import pickle
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, TypeGuard

import numpy as np

from evsmap.data import Frame, SemanticObservation, Sequence
from evsmap.errors import EvsmapError, InvalidDataError
from evsmap.interfaces import MapUpdater, Segmenter
from evsmap.measure.evaluators import MapEvaluator, SegmentationEvaluator
from evsmap.measure.memory import PeakMemory
from evsmap.readers.skipping import SkippedFrames, read_frames

if TYPE_CHECKING:  # the oracle is imported where it is used
    from evsmap.segmenters.oracle import OracleSegmenter

ORACLE_STAGE = "oracle"
"""The stage of a segmenter that reads ground truth (no network): kept apart from ``predict``
so that a segmentation + update rate never counts it as a network's time."""


# ------------------------------------------------------------------------------------- timing
@dataclass
class StageTimes:
    """Milliseconds per frame of each stage, in the order the stages first ran."""

    stages: dict[str, list[float]] = field(default_factory=dict)

    def add(self, stage: str, ms: float) -> None:
        self.stages.setdefault(stage, []).append(float(ms))

    def get(self, stage: str) -> list[float]:
        return self.stages.get(stage, [])

    def medians(self) -> dict[str, float]:
        """Median ms per frame of every stage that ran."""
        return {k: float(np.median(v)) for k, v in self.stages.items() if v}


def _ms_since(t0: float) -> float:
    return (time.perf_counter() - t0) * 1000.0


def timed_predict(segmenter: Segmenter, frame: Frame, times: StageTimes,
                  pixels: np.ndarray | None = None) -> SemanticObservation:
    """``segmenter.predict_at(frame, pixels)`` (the pixels the map reads, or None for all), its
    time added to ``times`` (stage ``predict``, or :data:`ORACLE_STAGE` for a segmenter that
    only reads ground truth) with the network's own stages (``last_timings``)."""
    t0 = time.perf_counter()
    observation = segmenter.predict_at(frame, pixels)
    ms = _ms_since(t0)
    if is_oracle(segmenter):
        times.add(ORACLE_STAGE, ms)
    else:
        times.add("predict", ms)
        for stage, value in (segmenter.last_timings or {}).items():
            times.add(stage, float(value))
    return observation


def timed_update(updater: MapUpdater, frame: Frame, observation: SemanticObservation | None,
                 times: StageTimes) -> None:
    """``updater.integrate(frame, observation)``, its time added to ``times`` (``update``)."""
    t0 = time.perf_counter()
    updater.integrate(frame, observation)
    times.add("update", _ms_since(t0))


def is_oracle(segmenter: Segmenter) -> TypeGuard[OracleSegmenter]:
    """Whether ``segmenter`` reads the ground truth instead of running a network."""
    from evsmap.segmenters.oracle import OracleSegmenter

    return isinstance(segmenter, OracleSegmenter)


def _indices(sequence: Sequence, indices: Iterable[int] | None, frames: int | None) -> list[int]:
    if indices is not None:
        return [int(i) for i in indices]
    n = len(sequence) if frames is None else max(0, min(int(frames), len(sequence)))
    return list(range(n))


def _timed_frames(sequence: Sequence, indices: list[int], times: StageTimes, *,
                  skip_bad: bool, skipped: SkippedFrames,
                  progress: Callable[[Any], Any] | None
                  ) -> Iterator[tuple[int, int, Frame]]:
    """``(position, index, frame)`` for each frame read, the read timed (``read``)."""
    order = indices if progress is None else progress(indices)
    frames = iter(read_frames(sequence, order, skip_bad=skip_bad, skipped=skipped))
    position = 0
    while True:
        t0 = time.perf_counter()
        try:
            index, frame = next(frames)
        except StopIteration:
            return
        times.add("read", _ms_since(t0))
        yield position, index, frame
        position += 1


# ------------------------------------------------------------------------------- segmentation
@dataclass
class SegmentationPass:
    """What :func:`run_segmentation` measured.

    Attributes:
        sequence: the sequence's name.
        indices: the frames segmented (those left out by ``skip_bad`` excluded).
        times: ms per frame of each stage (``read``, ``predict`` and the network's stages, or
            ``oracle``).
        skipped: the frames ``skip_bad`` left out, with the reason.
        results: each evaluator's ``evaluate()``, by the evaluator's ``name``.
    """

    sequence: str
    indices: list[int]
    times: StageTimes
    skipped: SkippedFrames
    results: dict[str, Any]

    @property
    def frames(self) -> int:
        return len(self.indices)

    @property
    def predict_ms(self) -> list[float]:
        """ms of each prediction (a network's; the oracle's under ``times`` ``oracle``)."""
        return self.times.get("predict") or self.times.get(ORACLE_STAGE)


def run_segmentation(sequence: Sequence, segmenter: Segmenter, *,
                     evaluators: Iterable[SegmentationEvaluator] = (),
                     indices: Iterable[int] | None = None, frames: int | None = None,
                     warmup: int = 0, skip_bad: bool = False,
                     progress: Callable[[Any], Any] | None = None) -> SegmentationPass:
    """Segment frames of ``sequence`` and hand each to ``evaluators``.

    Args:
        sequence: any reader's sequence.
        segmenter: any segmenter.
        evaluators: each gets ``reset()``, then per frame ``check(index, frame)`` before the
            prediction and ``process(index, frame, observation)`` after it, then
            ``evaluate()`` (its result under its ``name``).
        indices: the frames, in order (default: the first ``frames``, or all).
        frames: how many frames from the start when ``indices`` is not given.
        warmup: predictions on the first frame before the loop, not timed (a network's first
            calls allocate and tune).
        skip_bad: leave out frames the reader cannot read (listed in ``skipped``) instead of
            stopping at the first.
        progress: wraps the list of indices (a progress bar).
    """
    order = _indices(sequence, indices, frames)
    evaluators = list(evaluators)
    _check_names(evaluators)
    for ev in evaluators:
        ev.reset()
    if warmup and order:
        first = sequence.frame(order[0])
        for _ in range(int(warmup)):
            segmenter.predict(first)
    times, skipped, done = StageTimes(), SkippedFrames(), []
    for _, index, frame in _timed_frames(sequence, order, times, skip_bad=skip_bad,
                                         skipped=skipped, progress=progress):
        for ev in evaluators:
            ev.check(index, frame)
        observation = timed_predict(segmenter, frame, times)
        for ev in evaluators:
            ev.process(index, frame, observation)
        done.append(index)
    return SegmentationPass(sequence=sequence.name, indices=done, times=times, skipped=skipped,
                            results={ev.name: ev.evaluate() for ev in evaluators})


# ------------------------------------------------------------------------------------ mapping
@dataclass
class MappingPass:
    """What :func:`run_mapping` measured.

    Attributes:
        sequence: the sequence's name.
        updater: the map, after the last frame.
        indices: the frames integrated (those left out by ``skip_bad`` excluded).
        times: ms per frame of each stage (``read``, ``predict`` and the network's stages or
            ``oracle``, ``update``).
        skipped: the frames ``skip_bad`` left out, with the reason.
        memory: the peak resident memory of the mapping (from before the updater was made,
            when a factory was given, or before the first frame, to the last evaluator);
            ``None`` with ``measure_memory=False``.
        results: each map evaluator's ``evaluate(updater)``, by the evaluator's ``name``.
        segmenter_not_run: why the segmenter given was not run (the updater uses no
            semantics), else ``None``.
        threads: the threads each stage ran with (:class:`~evsmap.measure.pipelined.
            StageThreads`' record).
        wall_s: seconds from the first frame's read to the last frame's update (reading,
            segmentation and update, however they overlapped; not the warm-up nor the
            evaluators): ``frames / wall_s`` is ``wall_hz`` (docs/measurement.md).
        pipelined: whether the stages of consecutive frames overlapped
            (:mod:`evsmap.measure.pipelined`).
    """

    sequence: str
    updater: MapUpdater
    indices: list[int]
    times: StageTimes
    skipped: SkippedFrames
    memory: PeakMemory | None
    results: dict[str, Any]
    segmenter_not_run: str | None = None
    wall_s: float = float("nan")
    pipelined: bool = False
    threads: dict[str, Any] = field(default_factory=dict)

    @property
    def frames(self) -> int:
        return len(self.indices)

    @property
    def wall_hz(self) -> float:
        """``wall_hz``: frames / wall time (``nan`` without frames)."""
        return self.frames / self.wall_s if self.frames and self.wall_s > 0 else float("nan")

    @property
    def update_ms(self) -> list[float]:
        return self.times.get("update")

    @property
    def segment_ms(self) -> list[float]:
        """ms of each network prediction (empty with the oracle, with observations given, or
        with no segmenter run)."""
        return self.times.get("predict")


def rates(update_ms: list[float], segment_ms: list[float] | None = None) -> tuple[float, float]:
    """``(update_hz, segment_update_hz)``: ``1000 / median(update ms)`` and ``1000 / (median(update
    ms) + median(segmentation ms))`` (Table IV's "Runtime (Hz)": segmentation and update). The
    two medians may come from different numbers of frames: a network's time hardly depends on
    the frame, so it is timed until its median is precise enough rather than on every frame
    (:mod:`evsmap.measure.timing_policy`); ``nan`` without updates."""
    if not update_ms:
        return float("nan"), float("nan")
    update = float(np.median(np.asarray(update_ms, dtype=np.float64)))
    segment = float(np.median(np.asarray(segment_ms, dtype=np.float64))) if segment_ms else 0.0
    return 1000.0 / update, 1000.0 / (update + segment)


def run_mapping(sequence: Sequence, updater: MapUpdater | Callable[[], MapUpdater], *,
                segmenter: Segmenter | None = None,
                observations: list[SemanticObservation] | None = None,
                evaluators: Iterable[MapEvaluator] = (),
                indices: Iterable[int] | None = None, frames: int | None = None,
                skip_bad: bool = False, measure_memory: bool = True,
                progress: Callable[[Any], Any] | None = None, pipeline: bool = False,
                warmup: int = 0, threads: Any = None, growth: Any = None) -> MappingPass:
    """Integrate frames of ``sequence`` into a map, timing each stage.

    Args:
        sequence: a sequence with camera poses.
        updater: the map, or a function making it (then it is made inside the memory scope).
        segmenter: run on each frame, timed, when the updater uses semantics (an updater that
            uses none is mapped without it: ``segmenter_not_run`` says so).
        observations: the frames' observations computed beforehand, one per index in order
            (a cache); exclusive with ``segmenter``.
        evaluators: each gets ``evaluate(updater)`` after the last frame, inside the memory
            scope (writing the map's files is part of the mapping's memory).
        indices, frames, skip_bad, progress: as for :func:`run_segmentation`.
        measure_memory: measure the peak resident memory (resets the kernel's peak counter).
        pipeline: overlap reading, segmentation and the update of consecutive frames
            (:func:`~evsmap.measure.pipelined.pipelined_frames`); the updater sees the same
            frames and observations in the same order, so the map is the same.
        warmup: segmentations of the first frame before the loop, not timed (a network's first
            call builds its session, quantises and tunes: not a per-frame cost); with any, the
            first frame is also integrated into a scratch copy of the empty map, so that the
            update's compiled kernels load (or compile) outside the loop.
        threads: a :class:`~evsmap.measure.pipelined.StageThreads` set for the warm-up and
            the loop, then restored (default with ``pipeline``: the plan for the cores this
            process may use, the network on the CPU (:func:`~evsmap.measure.thread_plan.
            thread_plan`; ``PIPELINED`` on 2 cores); else ``SEQUENTIAL``: the libraries'
            defaults).
        growth: a :class:`~evsmap.measure.growth.MapGrowth`, called after every frame outside
            the timed update (its time is left out of ``wall_s``); its snapshots are
            ``results["growth"]``.
    """
    if not sequence.has_poses:
        raise EvsmapError(f"{sequence.name}: {sequence.meta.get('layout', 'this dataset')} has no "
                          f"camera poses (a segmentation dataset): nothing to map")
    if segmenter is not None and observations is not None:
        raise InvalidDataError("run_mapping: give a segmenter or observations, not both")
    order = _indices(sequence, indices, frames)
    if observations is not None and len(observations) != len(order):
        raise InvalidDataError(f"run_mapping: {len(observations)} observations for "
                               f"{len(order)} frames")
    evaluators = list(evaluators)
    _check_names(evaluators)
    times, update_times, skipped = StageTimes(), StageTimes(), SkippedFrames()
    done: list[int] = []
    memory = PeakMemory() if measure_memory else None
    not_run = None
    if memory is not None:
        memory.__enter__()
    try:
        the_map = updater() if callable(updater) and not isinstance(updater, MapUpdater) \
            else updater
        if segmenter is not None and not the_map.uses_semantics:
            not_run = f"the segmenter was not run: {type(the_map).__name__} uses no semantics"
            segmenter = None
        semantic = the_map.uses_semantics
        settings = threads if threads is not None else _default_threads(pipeline)
        with settings.applied(segmenter) as used:
            wall_s = _loop(sequence, order, the_map, segmenter, observations, semantic, times,
                           update_times, skipped, done, skip_bad=skip_bad, progress=progress,
                           pipeline=pipeline, warmup=warmup, growth=growth)
        times.stages["update"] = update_times.get("update")
        with the_map.reuse_tree():
            results = {ev.name: ev.evaluate(the_map) for ev in evaluators}
            if growth is not None:
                results["growth"] = growth.finish(len(done), the_map)
    finally:
        if memory is not None:
            memory.__exit__(None, None, None)
    return MappingPass(sequence=sequence.name, updater=the_map, indices=done, times=times,
                       skipped=skipped, memory=memory, results=results,
                       segmenter_not_run=not_run, wall_s=wall_s, pipelined=bool(pipeline),
                       threads=used)


def _loop(sequence: Sequence, order: list[int], the_map: MapUpdater,
          segmenter: Segmenter | None, observations: list[SemanticObservation] | None,
          semantic: bool, times: StageTimes, update_times: StageTimes,
          skipped: SkippedFrames, done: list[int], *, skip_bad: bool,
          progress: Callable[[Any], Any] | None, pipeline: bool, warmup: int,
          growth: Any = None) -> float:
    """:func:`run_mapping`'s warm-up and timed loop; returns the loop's wall seconds (without
    the ``growth`` snapshots' time)."""
    if warmup and order:
        first = sequence.frame(order[0])
        observation = observations[0] if observations is not None else None
        if segmenter is not None:
            for _ in range(int(warmup)):
                observation = segmenter.predict_at(first, the_map.semantic_pixels(first))
        if observation is not None or not semantic:
            _warm_update(the_map, first, observation if semantic else None)

    def observation_at(position: int, index: int) -> SemanticObservation | None:
        if observations is None or not semantic:
            return None
        return observations[order.index(index) if skipped.frames else position]

    aside = [0.0]

    def after(the_map: MapUpdater) -> None:
        # the last frame's snapshot is growth.finish's, with the evaluators, on the one tree
        # built of the finished map (MapUpdater.reuse_tree)
        if growth is not None and len(done) < len(order):
            t0 = time.perf_counter()
            growth.after_frame(len(done), the_map)
            aside[0] += time.perf_counter() - t0

    t_start = time.perf_counter()
    if pipeline:
        from evsmap.measure.pipelined import pipelined_frames

        segment_times = StageTimes()
        for position, index, frame, observation in pipelined_frames(
                sequence, order, segmenter=segmenter, read_times=times,
                segment_times=segment_times, timed_predict=timed_predict,
                needed=the_map.semantic_pixels,
                timed_frames=_timed_frames, skip_bad=skip_bad, skipped=skipped, progress=progress):
            if segmenter is None:
                observation = observation_at(position, index)
            timed_update(the_map, frame, observation, update_times)
            done.append(index)
            after(the_map)
        for stage, values in segment_times.stages.items():
            times.stages[stage] = values
    else:
        for position, index, frame in _timed_frames(sequence, order, times,
                                                    skip_bad=skip_bad, skipped=skipped,
                                                    progress=progress):
            observation = timed_predict(segmenter, frame, times,
                                        the_map.semantic_pixels(frame)) \
                if segmenter is not None else observation_at(position, index)
            timed_update(the_map, frame, observation, update_times)
            done.append(index)
            after(the_map)
    return time.perf_counter() - t_start - aside[0]


def _warm_update(the_map: MapUpdater, frame: Frame,
                 observation: SemanticObservation | None) -> None:
    """Integrate ``frame`` into a scratch copy of the still empty map, so that the update's
    compiled kernels load (or, on a fresh install, compile) before the timed loop, not in its
    first frame. A map that cannot be copied (held by a C++ library) is not warmed."""
    try:
        scratch = copy.deepcopy(the_map)
    except (TypeError, copy.Error, pickle.PicklingError):
        return
    scratch.integrate(frame, observation)


def in_memory(frames: list[Frame], name: str = "frames") -> Sequence:
    """Frames already read, as a sequence the engine can run (the benchmarks' and the gates'
    fixed frames)."""
    from evsmap.data import FrameList

    if not frames:
        raise InvalidDataError(f"{name}: no frames")
    return FrameList(name, frames[0].intrinsics, list(frames))


def _check_names(evaluators: list[Any]) -> None:
    names = [ev.name for ev in evaluators]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise InvalidDataError(f"two evaluators named {', '.join(twice)}: give each its own "
                               f"name")


def _default_threads(pipeline: bool) -> Any:
    """The loop's threads when the caller gives none: the pipelined loop's plan for this
    process's cores (the network on the CPU), or the sequential loop's library defaults."""
    from evsmap.measure.pipelined import SEQUENTIAL
    from evsmap.measure.thread_plan import available_cores, thread_plan

    return thread_plan(available_cores(), "cpu").threads if pipeline else SEQUENTIAL
