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
from evsmap.interfaces import MapUpdater, Segmenter
from evsmap.readers.skipping import SkippedFrames, read_frames


@dataclass(frozen=True)
class MappingRecord:
    """One sequence mapped by one updater.

    Attributes:
        updater, segmenter, sequence: names (segmenter ``None`` for geometry-only updaters).
        frames: frames integrated.
        resolution: leaf size, metres.
        update_ms: time of each ``integrate`` call (map update only), ms.
        segment_ms: time of each segmentation (``predict``), ms; empty without a segmenter.
        hz_median: ``1000 / median(update_ms)``.
        hz_end_to_end: ``1000 / median(update_ms + segment_ms)`` per frame (Table IV's
            "Runtime (Hz)": segmentation and update).
        map_bytes: size of the written map file (the paper's "Map Size").
        map_file: where it was written (``None`` when written to a temporary file).
        memory_bytes, nodes, leaves: the updater's in-memory size and octree counts.
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
    memory_bytes: int
    nodes: int
    leaves: int
    extra: dict[str, Any] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


def map_sequence(sequence: Sequence, updater: MapUpdater, *, updater_name: str,
                 segmenter: Segmenter | None = None, segmenter_name: str | None = None,
                 frames: int | None = None, out: str | PathLike[str] | None = None,
                 progress: Callable[[Any], Any] | None = None,
                 skip_bad: bool = False) -> MappingRecord:
    """Integrate the first ``frames`` frames of ``sequence`` (all by default) into ``updater``.

    Each frame is read (not timed), segmented when a segmenter is given (timed), then integrated
    (timed). The map is written to ``out`` (or a temporary file) and its byte size recorded.
    With ``skip_bad`` a frame that cannot be read is left out and listed in
    ``extra["skipped"]``; otherwise its error stops the run.
    """
    n = len(sequence) if frames is None else min(frames, len(sequence))
    update_ms: list[float] = []
    segment_ms: list[float] = []
    indices = range(n)
    if progress is not None:
        indices = progress(indices)
    skipped = SkippedFrames()
    for _, frame in read_frames(sequence, indices, skip_bad=skip_bad, skipped=skipped):
        observation = None
        if segmenter is not None:
            t0 = time.perf_counter()
            observation = segmenter.predict(frame)
            segment_ms.append((time.perf_counter() - t0) * 1000.0)
        t0 = time.perf_counter()
        updater.integrate(frame, observation)
        update_ms.append((time.perf_counter() - t0) * 1000.0)
    stats = updater.stats()
    if out is not None:
        path = Path(out)
        map_bytes = updater.write(path)
        map_file: str | None = str(path)
    else:
        with tempfile.TemporaryDirectory() as tmp:
            map_bytes = updater.write(Path(tmp) / "map.ot")
        map_file = None
    n = len(update_ms)
    upd = np.asarray(update_ms)
    total = upd + (np.asarray(segment_ms) if segment_ms else 0.0)
    return MappingRecord(
        updater=updater_name, segmenter=segmenter_name, sequence=sequence.name, frames=n,
        resolution=float(getattr(updater, "resolution", float("nan"))),
        update_ms=update_ms, segment_ms=segment_ms,
        hz_median=float(1000.0 / np.median(upd)) if n else float("nan"),
        hz_end_to_end=float(1000.0 / np.median(total)) if n else float("nan"),
        map_bytes=int(map_bytes), map_file=map_file, memory_bytes=stats.memory_bytes,
        nodes=stats.nodes, leaves=stats.leaves,
        extra={"skipped": skipped.as_dict()} if skip_bad else {})
