"""Facts about a sequence, as a plain record (the CLI and reports format it)."""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import Any

import numpy as np

from evsmap.classes import NYU40_CLASSES
from evsmap.data import Sequence
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
    names = class_names or getattr(sequence, "class_names", None) or NYU40_CLASSES
    depth_hist = np.zeros(65536, dtype=np.int64)  # 1/5000 m bins, exact for TUM-scaled depth
    far_hist: np.ndarray | None = None  # 1 cm bins beyond that range (outdoor stereo depth)
    far_max = 0.0
    sizes: dict[str, int] = {}
    valid = total = 0
    label_counts = np.zeros(256, dtype=np.int64)
    has_labels = False
    positions, stamps = [], []
    indices: Iterable[int] = range(len(sequence))
    if progress is not None:
        indices = progress(indices)
    cloud_points: list[int] = []
    ranges: list[np.ndarray] = []
    for _, frame in read_frames(sequence, indices, skip_bad=skip_bad, skipped=skipped):
        if frame.is_cloud:  # a point cloud: its "depth" is each point's range from the sensor
            ranges.append(np.linalg.norm(frame.points, axis=1))
            cloud_points.append(len(ranges[-1]))
            positions.append(frame.pose[:3, 3])
            stamps.append(frame.timestamp)
            continue
        d = frame.depth[frame.depth > 0]
        valid += d.size
        total += frame.depth.size
        dd = d.astype(np.float64)
        near = dd < _FAR_FROM_M
        depth_hist += np.bincount(np.round(dd[near] * 5000.0).astype(np.int64), minlength=65536)
        if not near.all():
            far = dd[~near]
            if far_hist is None:
                far_hist = np.zeros(_FAR_BINS, dtype=np.int64)
            far_hist += np.bincount(np.minimum((far - _FAR_FROM_M) / _FAR_STEP_M,
                                               _FAR_BINS - 1).astype(np.int64), minlength=_FAR_BINS)
            far_max = max(far_max, float(far.max()))
        size = f"{frame.width}x{frame.height}"
        sizes[size] = sizes.get(size, 0) + 1
        if frame.labels is not None:
            has_labels = True
            label_counts += np.bincount(frame.labels.ravel(), minlength=256)
        positions.append(frame.pose[:3, 3])
        stamps.append(frame.timestamp)
    pos = np.asarray(positions)
    record: dict[str, Any] = {
        "name": sequence.name,
        "layout": sequence.meta.get("layout", "unknown"),
        "frames": len(stamps),
    }
    if sequence.intrinsics is not None:
        record.update(width=sequence.intrinsics.width, height=sequence.intrinsics.height,
                      intrinsics=sequence.intrinsics.as_dict(),
                      intrinsics_source=sequence.meta.get("intrinsics_source", "reader"))
    if cloud_points:
        record["points_per_cloud"] = {"min": min(cloud_points), "max": max(cloud_points),
                                      "median": float(np.median(cloud_points))}
    if ranges:
        r = np.concatenate(ranges)
        p01, median, p99 = np.percentile(r, [1, 50, 99]) if r.size else (0.0, 0.0, 0.0)
        record["depth"] = {"min_m": float(r.min()), "max_m": float(r.max()), "p01_m": float(p01),
                           "median_m": float(median), "p99_m": float(p99),
                           "valid_fraction": 1.0} if r.size else {"valid_fraction": 0.0}
    elif valid:
        hist = depth_hist if far_hist is None else np.concatenate([depth_hist, far_hist])
        cdf = np.cumsum(hist) / valid

        def value(i: int) -> float:
            return float(i / 5000.0) if i < 65536 else _FAR_FROM_M + (i - 65536) * _FAR_STEP_M

        def q(p: float) -> float:
            return value(int(np.searchsorted(cdf, p)))

        nz = np.nonzero(hist)[0]
        record["depth"] = {
            "min_m": value(int(nz[0])), "max_m": far_max if far_hist is not None else value(
                int(nz[-1])),
            "p01_m": q(0.01), "median_m": q(0.5), "p99_m": q(0.99),
            "valid_fraction": valid / total,
        }
    else:
        record["depth"] = {"valid_fraction": 0.0}
    if len(sizes) > 1:  # mixed sensors (SUN RGB-D): frames per image size
        record["sizes"] = dict(sorted(sizes.items(), key=lambda kv: -kv[1]))
    if sequence.meta.get("poses") is False:  # a segmentation dataset: no camera poses
        record["poses"] = None
    elif len(pos):
        steps = np.linalg.norm(np.diff(pos, axis=0), axis=1) if len(pos) > 1 else np.zeros(0)
        record["poses"] = {
            "duration_s": float(stamps[-1] - stamps[0]),
            "path_length_m": float(steps.sum()),
            "extent_m": (pos.max(axis=0) - pos.min(axis=0)).tolist(),
            "start": pos[0].tolist(), "end": pos[-1].tolist(),
        }
    if has_labels:
        labelled = label_counts[:255].sum()
        present = np.nonzero(label_counts[:255])[0]
        record["labels"] = {
            "classes_present": len(present),
            "void_fraction": float(label_counts[255] / max(label_counts.sum(), 1)),
            "classes": [
                {"id": int(c), "name": names[c] if c < len(names) else f"class {c}",
                 "fraction": float(label_counts[c] / max(labelled, 1))}
                for c in present
            ],
        }
    else:
        record["labels"] = None
    for key in ("dropped", "synthetic", "scene", "seed", "split", "pose_source",
                "time_source_reason"):
        if key in sequence.meta:
            record[key] = sequence.meta[key]
    return record
