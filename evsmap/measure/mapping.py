"""Mapping measurement (Table IV): integrate a sequence with one updater and record its rates
(the update alone, segmentation and update, the whole loop's) and the map's size.

:class:`MappingRecord` is the one record of a mapping run: ``evsmap map --json`` prints it and
the runner's ``extra/mapping/...`` records store its :meth:`MappingRecord.values`
(docs/measurement.md, "Quantities")."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from os import PathLike
from typing import Any

from evsmap.data import Sequence
from evsmap.errors import InvalidDataError
from evsmap.interfaces import FILE_FORMATS, MapUpdater, Segmenter
from evsmap.measure.engine import MappingPass, StageTimes, is_oracle, rates, run_mapping
from evsmap.measure.evaluators import (
    MapFiles,
    MapStatistics,
    pruned_share,
    write_map,
)

__all__ = ["MappingRecord", "map_sequence", "map_sizes", "pruned_share", "write_map"]


@dataclass(frozen=True)
class MappingRecord:
    """One sequence mapped by one updater.

    Attributes:
        updater, segmenter, sequence: names (segmenter ``None`` for geometry-only updaters).
        frames: frames integrated.
        resolution: leaf size, metres.
        update_ms: time of each ``integrate`` call (map update only), ms.
        segment_ms: time of each segmentation by a network (``predict``), ms; empty without
            one, with the oracle (its time is the ``oracle`` stage, not a network's) and for
            updaters that use no semantics (the segmenter is not run).
        stages_ms: per-frame times of every stage that ran, ms: ``read`` (the reader),
            ``preprocess`` / ``network`` / ``postprocess`` (a network segmenter's
            ``last_timings``), ``oracle``, ``update``.
        update_hz: ``1000 / median(update_ms)``: the map update alone.
        segment_update_hz: ``1000 / (median(update_ms) + median(segment_ms))`` (Table IV's
            "Runtime (Hz)": segmentation and update, one after the other, reading excluded;
            the update alone without a network's segmentation).
        wall_hz: frames / wall time of the whole loop, reading, segmentation and update
            included, however they overlapped (``wall_s``; the segmenter's warm-up and the
            map's writing excluded): what a robot streaming the sequence gets.
        wall_s: the loop's wall time, seconds.
        pipeline: how the loop ran: ``enabled`` (reading, segmentation and update of
            consecutive frames overlapped, :mod:`evsmap.measure.pipelined`) and the threads of
            each stage.
        map_bytes: size of the written map file (the paper's "Map Size"), in ``file_format``.
        map_file: where it was written (``None`` when written to a temporary file).
        file_format: one of :data:`~evsmap.interfaces.FILE_FORMATS` (``"full"`` the resumable
            state, ``"published"`` the file the compared system itself saves, ...), see
            :meth:`OctreeUpdater.write`.
        map_bytes_full, map_bytes_published, map_bytes_colour: the ``.ot`` size in each format
            (always measured; full and published are equal where the system writes its full
            state; colour ``None`` for a map without a colour form).
        map_bytes_message: the size of the map as the system's ROS node sends it
            (``octomap_full``): the ``message`` file where the system sends another form than
            it saves (SSMI), else the saved file's.
        front_end: how frames became hits and misses: ``name`` (``generator``, ``direct`` or
            ``None``) and, per frame, ``centroids``, ``hits`` and ``rays``
            (:meth:`~evsmap.interfaces.MapUpdater.front_end_counts`).
        nodes, leaves: the map's octree counts.
        octomap_memory_bytes: OctoMap's ``memoryUsage()`` formula over the tree's nodes in the
            compared system's C++ node type (a model of the C++ memory, not a measurement).
        map_nbytes: measured - the bytes of the arrays evsmap holds the map in (the sum of
            their ``nbytes``); ``None`` for a map held by a C++ library (see the peak RSS).
        peak_rss_bytes: measured - the process's peak resident memory while the sequence was
            read, segmented and mapped and the map written (``start_rss_bytes`` when it
            began, after the network and the reader were loaded); ``peak_scope`` is
            ``"run"``, or ``"process"`` where the kernel's peak could not be reset (then
            since the process started).
    """

    updater: str
    segmenter: str | None
    sequence: str
    frames: int
    resolution: float
    update_ms: list[float]
    segment_ms: list[float]
    update_hz: float
    segment_update_hz: float
    wall_hz: float
    map_bytes: int
    map_file: str | None
    octomap_memory_bytes: int | None
    nodes: int
    leaves: int
    file_format: str = "full"
    map_bytes_full: int | None = None
    map_bytes_published: int | None = None
    map_bytes_colour: int | None = None
    map_bytes_message: int | None = None
    front_end: dict[str, Any] = field(default_factory=dict)
    stages_ms: dict[str, list[float]] = field(default_factory=dict)
    map_nbytes: int | None = None
    peak_rss_bytes: int | None = None
    start_rss_bytes: int | None = None
    peak_scope: str | None = None
    wall_s: float = float("nan")
    pipeline: dict[str, Any] = field(default_factory=dict)
    extra: dict[str, Any] = field(default_factory=dict)

    @classmethod
    def from_run(cls, run: MappingPass, *, updater: str, segmenter: str | None,
                 file_format: str = "full", segment_ms: list[float] | None = None,
                 extra: dict[str, Any] | None = None) -> MappingRecord:
        """The record of ``run`` (:func:`~evsmap.measure.engine.run_mapping` with the
        ``stats`` and ``files`` evaluators); ``segment_ms``: the segmentation times when the
        observations were computed beforehand (default: the run's own)."""
        segment = list(run.segment_ms if segment_ms is None else segment_ms)
        update_hz, segment_update_hz = rates(run.update_ms, segment)
        stats, files, memory = run.results["stats"], run.results["files"], run.memory
        the_map = run.updater
        return cls(
            updater=updater, segmenter=segmenter, sequence=run.sequence, frames=run.frames,
            resolution=float(the_map.resolution), update_ms=list(run.update_ms),
            segment_ms=segment, update_hz=update_hz, segment_update_hz=segment_update_hz,
            wall_hz=run.wall_hz, wall_s=run.wall_s,
            pipeline={"enabled": run.pipelined, **run.threads},
            map_bytes=int(files.written_bytes), map_file=files.file,
            octomap_memory_bytes=stats.octomap_memory_bytes, nodes=stats.nodes,
            leaves=stats.leaves, file_format=file_format,
            map_bytes_full=files.sizes["full"], map_bytes_published=files.sizes["published"],
            map_bytes_colour=files.sizes.get("colour"),
            map_bytes_message=files.sizes.get("message", files.sizes["published"]),
            front_end={"name": the_map.front_end, **the_map.front_end_counts()},
            stages_ms=_record_stages(run.times.stages), map_nbytes=stats.map_nbytes,
            peak_rss_bytes=None if memory is None else memory.peak_rss_bytes,
            start_rss_bytes=None if memory is None else memory.start_rss_bytes,
            peak_scope=None if memory is None else
            "run" if memory.scope == "block" else "process", extra=dict(extra or {}))

    @property
    def rss_added_bytes(self) -> int | None:
        """The peak resident memory above the run's start (the map's own working memory)."""
        if self.peak_rss_bytes is None or self.start_rss_bytes is None:
            return None
        return max(0, self.peak_rss_bytes - self.start_rss_bytes)

    def values(self) -> dict[str, float]:
        """The record's numbers as the runner stores them (a cell record's ``values``, base
        units): frames, ``update_hz``, ``segment_update_hz``, ``map_bytes`` (the saved file,
        ``published``), the other sizes, counts and memory readings that were measured."""
        published, full = self.map_bytes_published, self.map_bytes_full
        values = {"frames": float(self.frames), "update_hz": self.update_hz,
                  "segment_update_hz": self.segment_update_hz,
                  "map_bytes": float(self.map_bytes if published is None else published),
                  "map_bytes_full": float(self.map_bytes if full is None else full),
                  "nodes": float(self.nodes), "leaves": float(self.leaves)}
        optional = {"peak_rss_bytes": self.peak_rss_bytes,
                    "rss_added_bytes": self.rss_added_bytes,
                    "map_bytes_colour": self.map_bytes_colour,
                    "map_bytes_message": self.map_bytes_message,
                    "octomap_memory_bytes": self.octomap_memory_bytes,
                    "map_nbytes": self.map_nbytes}
        values.update({k: float(v) for k, v in optional.items() if v is not None})
        return values

    def stage_medians(self) -> dict[str, float]:
        """Median ms per frame of each stage in :attr:`stages_ms`."""
        return StageTimes(dict(self.stages_ms)).medians()

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


def map_sizes(updater: MapUpdater) -> dict[str, int]:
    """The ``.ot`` size of the map in each file format, written to a temporary folder."""
    return dict(MapFiles().evaluate(updater).sizes)


def map_sequence(sequence: Sequence, updater: MapUpdater, *, updater_name: str,
                 segmenter: Segmenter | None = None, segmenter_name: str | None = None,
                 frames: int | None = None, out: str | PathLike[str] | None = None,
                 progress: Callable[[Any], Any] | None = None,
                 skip_bad: bool = False, file_format: str = "full", pipeline: bool = False,
                 threads: Any = None) -> MappingRecord:
    """Integrate the first ``frames`` frames of ``sequence`` (all by default) into ``updater``
    (``evsmap map``; :func:`evsmap.measure.engine.run_mapping` times it).

    Each frame is read, segmented when a segmenter is given, then integrated; every stage is
    timed. The map is written to ``out`` (or a temporary file) and its byte size recorded.
    With ``skip_bad`` a frame that cannot be read is left out and listed in
    ``extra["skipped"]``; otherwise its error stops the run. With ``pipeline`` the stages of
    consecutive frames overlap (the same map); ``threads`` (a
    :class:`~evsmap.measure.pipelined.StageThreads`; default: the loop's own) sets each stage's
    threads, recorded under ``pipeline``. A network segmenter is warmed up on the first frame
    before the timed loop.
    """
    if file_format not in FILE_FORMATS:
        raise InvalidDataError(f"file format must be one of {', '.join(FILE_FORMATS)}, got "
                               f"{file_format!r}")
    warm = int(segmenter is not None and not is_oracle(segmenter))
    run = run_mapping(sequence, updater, segmenter=segmenter, frames=frames, skip_bad=skip_bad,
                      progress=progress, pipeline=pipeline, warmup=warm, threads=threads,
                      evaluators=[MapStatistics(), MapFiles(out=out, file_format=file_format)])
    extra: dict[str, Any] = {}
    if run.segmenter_not_run is not None:
        extra["segmenter_not_run"] = (f"{segmenter_name or 'the segmenter'} was not run: "
                                      f"{updater_name} uses no semantics")
        segmenter_name = None
    if skip_bad:
        extra["skipped"] = run.skipped.as_dict()
    return MappingRecord.from_run(run, updater=updater_name, segmenter=segmenter_name,
                                  file_format=file_format, extra=extra)


def _record_stages(stages: dict[str, list[float]]) -> dict[str, list[float]]:
    """The engine's stages under the record's names (a network's ``predict`` is split into
    its own ``preprocess`` / ``network`` / ``postprocess`` stages, so it is not repeated)."""
    return {k: list(v) for k, v in stages.items() if k != "predict"}
