"""How a map grows with the frames integrated: its node count and its size under each reading
(the saved file, the octomap_full message, the colour-only file, OctoMap's memory model) every few
frames.

Pruning, and so any claim about map size, grows with repeated observations of the same space;
:class:`MapGrowth` is handed to :func:`evsmap.measure.engine.run_mapping`, which calls it after
every frame outside the timed update and leaves its time out of the loop's wall time.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from evsmap.interfaces import MapUpdater

GROWTH_POINTS = 12
"""Snapshots a mapping run takes, about evenly spaced (the last frame always)."""

SHORT_GROWTH_POINTS = 2
"""The same on a sequence of fewer than :data:`LONG_SEQUENCE` frames: half-way and at the end
(each snapshot builds the tree and measures every file reading: 1-5 s at 2 cm)."""

QUICK_GROWTH_POINTS = 1
"""The same in a ``--quick`` run: the end only, read off the finished map's one tree (the
half-way snapshot built a tree of its own: about 1 s of each of the 15 quick mapping runs)."""

LONG_SEQUENCE = 300
"""Frames from which a sequence gets :data:`GROWTH_POINTS` snapshots."""


def growth_points(frames: int, *, quick: bool = False) -> int:
    """How many snapshots a mapping run of ``frames`` takes."""
    if quick:
        return QUICK_GROWTH_POINTS
    return GROWTH_POINTS if frames >= LONG_SEQUENCE else SHORT_GROWTH_POINTS


def growth_every(frames: int, points: int = GROWTH_POINTS) -> int:
    """The snapshot period giving about ``points`` snapshots over ``frames``."""
    return max(1, -(-int(frames) // max(1, int(points))))


def snapshot(frames: int, updater: MapUpdater) -> dict[str, Any]:
    """The map after ``frames`` frames: nodes, leaves and bytes under each reading
    (:meth:`~evsmap.interfaces.MapUpdater.size_readings`)."""
    return {"frames": int(frames), **updater.size_readings()}


@dataclass
class MapGrowth:
    """Snapshots every ``every`` frames (and after the last one).

    Attributes:
        every: the period, in frames integrated.
        points: the snapshots (:func:`snapshot`), in order.
    """

    every: int
    points: list[dict[str, Any]] = field(default_factory=list)

    def after_frame(self, frames: int, updater: MapUpdater) -> None:
        if frames % self.every == 0:
            self.points.append(snapshot(frames, updater))

    def finish(self, frames: int, updater: MapUpdater) -> list[dict[str, Any]]:
        if frames and (not self.points or self.points[-1]["frames"] != frames):
            self.points.append(snapshot(frames, updater))
        return list(self.points)
