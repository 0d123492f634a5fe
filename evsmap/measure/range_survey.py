"""How far a sequence's measurements lie from the sensor, against a map's ``max_range``: the
check behind ``evsmap map``'s warning that most points are cut (a lidar bag mapped with the
RGB-D default of 5 m inserts free space only).

Distances are along each ray, sensor to point: for a depth image ``depth * |K^-1 (u, v, 1)|``
(the pixel's ray length, not its z), for a point cloud the points' norm in the sensor frame,
the distance the map's range test uses (:mod:`evsmap.mapping.raycast`).
"""

from __future__ import annotations

from collections.abc import Sequence as Indices
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from evsmap.data import Frame


@dataclass(frozen=True)
class RangeSurvey:
    """The distances of the valid measurements of a few frames.

    Attributes:
        frames: the frame indices surveyed.
        points: valid measurements in them (depth > 0, or cloud points).
        beyond: those farther than ``max_range``.
        max_range: the range tested (metres).
        min_m, median_m, p95_m, max_m: their distances (None without a point).
    """

    frames: tuple[int, ...]
    points: int
    beyond: int
    max_range: float
    min_m: float | None
    median_m: float | None
    p95_m: float | None
    max_m: float | None

    @property
    def share_beyond(self) -> float:
        return self.beyond / self.points if self.points else 0.0

    def as_dict(self) -> dict[str, Any]:
        return {**asdict(self), "frames": list(self.frames), "share_beyond": self.share_beyond}


def ray_lengths(frame: Frame) -> np.ndarray:
    """``float64`` sensor-to-point distance of every valid measurement of ``frame``."""
    if frame.is_cloud:
        norms: npt.NDArray[np.float64] = np.linalg.norm(
            np.asarray(frame.points, dtype=np.float64), axis=1)
        return norms
    depth = frame.depth
    intr = frame.intrinsics
    assert depth is not None and intr is not None  # an image frame (Frame's invariant)
    v, u = np.nonzero(depth > 0)
    x = (u - intr.cx) / intr.fx
    y = (v - intr.cy) / intr.fy
    return depth[v, u].astype(np.float64) * np.sqrt(x * x + y * y + 1.0)


def survey_indices(count: int, samples: int = 3) -> list[int]:
    """Up to ``samples`` frame indices spread over ``0..count-1`` (first, middle, last)."""
    if count <= 0:
        return []
    return sorted({round(i * (count - 1) / max(samples - 1, 1)) for i in range(samples)})


def survey_ranges(frames: Indices[tuple[int, Frame]], max_range: float) -> RangeSurvey:
    """The :class:`RangeSurvey` of ``(index, frame)`` pairs against ``max_range`` (negative:
    no limit, nothing is beyond)."""
    lengths = [ray_lengths(frame) for _, frame in frames]
    all_lengths = np.concatenate(lengths) if lengths else np.zeros(0)
    beyond = int(np.count_nonzero(all_lengths > max_range)) if max_range >= 0 else 0
    stats: list[float | None] = [None] * 4
    if len(all_lengths):
        stats = [float(v) for v in np.percentile(all_lengths, [0, 50, 95, 100])]
    return RangeSurvey(frames=tuple(i for i, _ in frames), points=int(len(all_lengths)),
                       beyond=beyond, max_range=float(max_range), min_m=stats[0],
                       median_m=stats[1], p95_m=stats[2], max_m=stats[3])
