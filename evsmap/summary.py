"""Facts about a sequence, as a plain record (the CLI and reports format it)."""

from __future__ import annotations

from collections.abc import Callable, Iterable
from collections.abc import Sequence as Sequence_
from typing import Any

import numpy as np

from evsmap.classes import NYU40_CLASSES
from evsmap.data import Frame, Sequence
from evsmap.readers.skipping import SkippedFrames, read_frames

_FAR_FROM_M = 65535.5 / 5000.0  # depth at and beyond this goes to the coarse histogram
_FAR_STEP_M = 0.01
_FAR_BINS = 1_000_000  # up to 10 km; the maximum itself is exact


def summarize_sequence(
    sequence: Sequence, *, progress: Callable[[Iterable[int]], Iterable[int]] | None = None,
    class_names: tuple[str, ...] | None = None, skip_bad: bool = False,
    skipped: SkippedFrames | None = None,
) -> dict[str, Any]:
    """Read every frame once and return frames, resolution, depth statistics, pose span and the
    label classes present (with pixel fractions of all labelled pixels). With ``skip_bad``,
    frames that cannot be read are left out and listed in ``skipped``. ``progress`` wraps the
    frame indices."""
    names = class_names or sequence.class_names or NYU40_CLASSES
    indices: Iterable[int] = range(len(sequence))
    if progress is not None:
        indices = progress(indices)
    tally = _Tally()
    for _, frame in read_frames(sequence, indices, skip_bad=skip_bad, skipped=skipped):
        tally.add(frame)
    record: dict[str, Any] = {
        "name": sequence.name,
        "layout": sequence.meta.get("layout", "unknown"),
        "frames": len(tally.stamps),
    }
    if sequence.intrinsics is not None:
        record.update(width=sequence.intrinsics.width, height=sequence.intrinsics.height,
                      intrinsics=sequence.intrinsics.as_dict(),
                      intrinsics_source=sequence.meta.get("intrinsics_source", "reader"))
    if tally.cloud_points:
        record["points_per_cloud"] = {"min": min(tally.cloud_points),
                                      "max": max(tally.cloud_points),
                                      "median": float(np.median(tally.cloud_points))}
    record["depth"] = tally.depth()
    if len(tally.sizes) > 1:  # mixed sensors (SUN RGB-D): frames per image size
        record["sizes"] = dict(sorted(tally.sizes.items(), key=lambda kv: -kv[1]))
    if sequence.meta.get("poses") is False:  # a segmentation dataset: no camera poses
        record["poses"] = None
    elif tally.positions:
        record["poses"] = tally.poses()
    record["labels"] = tally.labels(names) if tally.has_labels else None
    for key in ("dropped", "synthetic", "scene", "seed", "split", "pose_source",
                "time_source_reason"):
        if key in sequence.meta:
            record[key] = sequence.meta[key]
    if sequence.has_ground_truth:
        record["ground_truth"] = sequence.meta.get("ground_truth_source", "ground-truth voxels")
    return record


class _Tally:
    """What :func:`summarize_sequence` counts over the frames."""

    def __init__(self) -> None:
        self.depth_hist = np.zeros(65536, dtype=np.int64)  # 1/5000 m bins: TUM-scaled depth
        self.far_hist: np.ndarray | None = None  # 1 cm bins beyond (outdoor stereo depth)
        self.far_max = 0.0
        self.sizes: dict[str, int] = {}
        self.valid = self.total = 0
        self.label_counts = np.zeros(256, dtype=np.int64)
        self.has_labels = False
        self.positions: list[np.ndarray] = []
        self.stamps: list[float] = []
        self.cloud_points: list[int] = []
        self.ranges: list[np.ndarray] = []

    def add(self, frame: Frame) -> None:
        """Count one frame: a point cloud's ranges, or an image's depth, size and labels."""
        if frame.points is not None:  # a point cloud: its "depth" is each point's range
            self.ranges.append(np.linalg.norm(frame.points, axis=1))
            self.cloud_points.append(len(self.ranges[-1]))
        else:
            assert frame.depth is not None, "a frame without a point cloud has a depth image"
            self._add_image(frame, frame.depth)
        self.positions.append(frame.pose[:3, 3])
        self.stamps.append(frame.timestamp)

    def _add_image(self, frame: Frame, depth: np.ndarray) -> None:
        d = depth[depth > 0]
        self.valid += d.size
        self.total += depth.size
        dd = d.astype(np.float64)
        near = dd < _FAR_FROM_M
        self.depth_hist += np.bincount(np.round(dd[near] * 5000.0).astype(np.int64),
                                       minlength=65536)
        if not near.all():
            far = dd[~near]
            if self.far_hist is None:
                self.far_hist = np.zeros(_FAR_BINS, dtype=np.int64)
            self.far_hist += np.bincount(np.minimum((far - _FAR_FROM_M) / _FAR_STEP_M,
                                                    _FAR_BINS - 1).astype(np.int64),
                                         minlength=_FAR_BINS)
            self.far_max = max(self.far_max, float(far.max()))
        size = f"{frame.width}x{frame.height}"
        self.sizes[size] = self.sizes.get(size, 0) + 1
        if frame.labels is not None:
            self.has_labels = True
            self.label_counts += np.bincount(frame.labels.ravel(), minlength=256)

    def depth(self) -> dict[str, Any]:
        """Depth statistics: of the clouds' ranges, else of the images' valid depth."""
        if self.ranges:
            r = np.concatenate(self.ranges)
            if not r.size:
                return {"valid_fraction": 0.0}
            p01, median, p99 = np.percentile(r, [1, 50, 99])
            return {"min_m": float(r.min()), "max_m": float(r.max()), "p01_m": float(p01),
                    "median_m": float(median), "p99_m": float(p99), "valid_fraction": 1.0}
        if not self.valid:
            return {"valid_fraction": 0.0}
        far_hist = self.far_hist
        hist = self.depth_hist if far_hist is None else np.concatenate([self.depth_hist,
                                                                        far_hist])
        cdf = np.cumsum(hist) / self.valid

        def value(i: int) -> float:
            return float(i / 5000.0) if i < 65536 else _FAR_FROM_M + (i - 65536) * _FAR_STEP_M

        def q(p: float) -> float:
            return value(int(np.searchsorted(cdf, p)))

        nz = np.nonzero(hist)[0]
        return {
            "min_m": value(int(nz[0])),
            "max_m": self.far_max if far_hist is not None else value(int(nz[-1])),
            "p01_m": q(0.01), "median_m": q(0.5), "p99_m": q(0.99),
            "valid_fraction": self.valid / self.total,
        }

    def poses(self) -> dict[str, Any]:
        """The camera path: duration, length, extent, start and end."""
        pos = np.asarray(self.positions)
        steps = np.linalg.norm(np.diff(pos, axis=0), axis=1) if len(pos) > 1 else np.zeros(0)
        return {
            "duration_s": float(self.stamps[-1] - self.stamps[0]),
            "path_length_m": float(steps.sum()),
            "extent_m": (pos.max(axis=0) - pos.min(axis=0)).tolist(),
            "start": pos[0].tolist(), "end": pos[-1].tolist(),
        }

    def labels(self, names: Sequence_[str]) -> dict[str, Any]:
        """The label classes present, with their share of the labelled pixels."""
        counts = self.label_counts
        labelled = counts[:255].sum()
        present = np.nonzero(counts[:255])[0]
        return {
            "classes_present": len(present),
            "void_fraction": float(counts[255] / max(counts.sum(), 1)),
            "classes": [
                {"id": int(c), "name": names[int(c)] if c < len(names) else f"class {c}",
                 "fraction": float(counts[c] / max(labelled, 1))}
                for c in present
            ],
        }
