"""Mapping measurement (Table IV): integrate a sequence with one updater and record the update
rate, the end-to-end rate with segmentation, and the map's size."""

from __future__ import annotations

import tempfile
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np

from evsmap.data import Sequence
from evsmap.errors import EvsmapError, InvalidDataError
from evsmap.interfaces import MapUpdater, Segmenter
from evsmap.measure.memory import PeakMemory
from evsmap.readers.skipping import SkippedFrames, read_frames


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
        hz_median: ``1000 / median(update_ms)``.
        hz_end_to_end: ``1000 / median(update_ms + segment_ms)`` per frame (Table IV's
            "Runtime (Hz)": segmentation and update).
        map_bytes: size of the written map file (the paper's "Map Size"), in ``file_format``.
        map_file: where it was written (``None`` when written to a temporary file).
        file_format: ``"full"`` (the resumable state) or ``"published"`` (what the compared
            system itself writes), see :meth:`OctreeUpdater.write`.
        map_bytes_full, map_bytes_published: the ``.ot`` size in each format (both always
            measured; equal where the system writes its full state).
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
    hz_median: float
    hz_end_to_end: float
    map_bytes: int
    map_file: str | None
    octomap_memory_bytes: int | None
    nodes: int
    leaves: int
    file_format: str = "full"
    map_bytes_full: int | None = None
    map_bytes_published: int | None = None
    stages_ms: dict[str, list[float]] = field(default_factory=dict)
    map_nbytes: int | None = None
    peak_rss_bytes: int | None = None
    start_rss_bytes: int | None = None
    peak_scope: str | None = None
    extra: dict[str, Any] = field(default_factory=dict)

    def stage_medians(self) -> dict[str, float]:
        """Median ms per frame of each stage in :attr:`stages_ms`."""
        return {k: float(np.median(v)) for k, v in self.stages_ms.items() if v}

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


def write_map(updater: MapUpdater, path: str | PathLike[str], file_format: str = "full") -> int:
    """``updater.write(path, file_format)``; a plug-in whose ``write`` takes no file format
    writes one file, which is both its full and its published one."""
    import inspect

    if file_format not in ("full", "published"):
        raise InvalidDataError(f"file format must be full or published, got {file_format!r}")
    if file_format != "full" and "file_format" in inspect.signature(updater.write).parameters:
        return int(updater.write(path, file_format=file_format))
    return int(updater.write(path))


def pruned_share(updater: MapUpdater) -> float | None:
    """The share of the finest leaves merged into pruned nodes (octree updaters), else None."""
    tree_of = getattr(updater, "tree", None)
    leaves = getattr(getattr(updater, "map", None), "num_leaves", None)
    if not callable(tree_of) or not leaves:
        return None
    from evsmap.mapping.keys import TREE_DEPTH

    tree = tree_of()
    finest = int(np.count_nonzero(tree.is_leaf & (tree.depth == TREE_DEPTH)))
    return 1.0 - finest / int(leaves)


def map_sizes(updater: MapUpdater) -> dict[str, int]:
    """The ``.ot`` size of the map in each file format, written to a temporary folder."""
    with tempfile.TemporaryDirectory() as tmp:
        return {fmt: write_map(updater, Path(tmp) / f"{fmt}.ot", fmt)
                for fmt in ("full", "published")}


def map_sequence(sequence: Sequence, updater: MapUpdater, *, updater_name: str,
                 segmenter: Segmenter | None = None, segmenter_name: str | None = None,
                 frames: int | None = None, out: str | PathLike[str] | None = None,
                 progress: Callable[[Any], Any] | None = None,
                 skip_bad: bool = False, file_format: str = "full") -> MappingRecord:
    """Integrate the first ``frames`` frames of ``sequence`` (all by default) into ``updater``.

    Each frame is read (not timed), segmented when a segmenter is given (timed), then integrated
    (timed). The map is written to ``out`` (or a temporary file) and its byte size recorded.
    With ``skip_bad`` a frame that cannot be read is left out and listed in
    ``extra["skipped"]``; otherwise its error stops the run.
    """
    from evsmap.segmenters.oracle import OracleSegmenter

    if not sequence.has_poses:
        raise EvsmapError(f"{sequence.name}: {sequence.meta.get('layout', 'this dataset')} has no "
                          f"camera poses (a segmentation dataset): nothing to map")
    n = len(sequence) if frames is None else min(frames, len(sequence))
    update_ms: list[float] = []
    segment_ms: list[float] = []
    stages: dict[str, list[float]] = {}
    extra: dict[str, Any] = {}
    indices = range(n)
    if progress is not None:
        indices = progress(indices)
    skipped = SkippedFrames()
    if segmenter is not None and not updater.uses_semantics:
        extra["segmenter_not_run"] = (f"{segmenter_name or 'the segmenter'} was not run: "
                                      f"{updater_name} uses no semantics")
        segmenter = segmenter_name = None
    oracle = isinstance(segmenter, OracleSegmenter)
    frames_read = iter(read_frames(sequence, indices, skip_bad=skip_bad, skipped=skipped))
    with PeakMemory() as memory:
        while True:
            t0 = time.perf_counter()
            try:
                _, frame = next(frames_read)
            except StopIteration:
                break
            stages.setdefault("read", []).append((time.perf_counter() - t0) * 1000.0)
            observation = None
            if segmenter is not None:
                t0 = time.perf_counter()
                observation = segmenter.predict(frame)
                ms = (time.perf_counter() - t0) * 1000.0
                if oracle:
                    stages.setdefault("oracle", []).append(ms)
                else:
                    segment_ms.append(ms)
                    for stage, value in segmenter.last_timings.items():
                        stages.setdefault(stage, []).append(float(value))
            t0 = time.perf_counter()
            updater.integrate(frame, observation)
            update_ms.append((time.perf_counter() - t0) * 1000.0)
            stages.setdefault("update", []).append(update_ms[-1])
        stats = updater.stats()  # the tree and the files are part of the run's memory
        sizes = map_sizes(updater)
        if out is not None:
            path = Path(out)
            map_bytes = write_map(updater, path, file_format)
            map_file: str | None = str(path)
        else:
            map_bytes = sizes[file_format]
            map_file = None
    n = len(update_ms)
    upd = np.asarray(update_ms)
    total = upd + (np.asarray(segment_ms) if segment_ms else 0.0)
    return MappingRecord(
        updater=updater_name, segmenter=segmenter_name, sequence=sequence.name, frames=n,
        resolution=float(updater.resolution),
        update_ms=update_ms, segment_ms=segment_ms,
        hz_median=float(1000.0 / np.median(upd)) if n else float("nan"),
        hz_end_to_end=float(1000.0 / np.median(total)) if n else float("nan"),
        map_bytes=int(map_bytes), map_file=map_file,
        octomap_memory_bytes=stats.octomap_memory_bytes, nodes=stats.nodes,
        leaves=stats.leaves, file_format=file_format,
        map_bytes_full=sizes["full"], map_bytes_published=sizes["published"],
        stages_ms=stages, map_nbytes=updater.memory_nbytes(),
        peak_rss_bytes=memory.peak_rss_bytes, start_rss_bytes=memory.start_rss_bytes,
        peak_scope="run" if memory.scope == "block" else "process",
        extra={**extra, **({"skipped": skipped.as_dict()} if skip_bad else {})})
