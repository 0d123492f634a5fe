"""How a map grows with the frames integrated: its node count and its size under each reading
(the published file, the colour-only file, OctoMap's memory model) every few frames.

Pruning, and so any claim about map size, grows with repeated observations of the same space;
:class:`MapGrowth` is handed to :func:`evsmap.measure.engine.run_mapping`, which calls it after
every frame outside the timed update and leaves its time out of the loop's wall time.
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from evsmap.interfaces import MapUpdater

GROWTH_POINTS = 12
"""Snapshots a mapping run takes, about evenly spaced (the last frame always)."""


def growth_every(frames: int, points: int = GROWTH_POINTS) -> int:
    """The snapshot period giving about ``points`` snapshots over ``frames``."""
    return max(1, -(-int(frames) // max(1, int(points))))


def snapshot(frames: int, updater: MapUpdater) -> dict[str, Any]:
    """The map after ``frames`` frames: nodes, leaves and bytes under each reading (None where
    the updater has no such file or model)."""
    from evsmap.measure.evaluators import write_map

    stats = updater.stats()
    sizes: dict[str, int | None] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for fmt in ("published", "colour"):
            sizes[fmt] = (write_map(updater, Path(tmp) / f"{fmt}.ot", fmt)
                          if fmt in updater.file_formats() else None)
    return {"frames": int(frames), "nodes": int(stats.nodes), "leaves": int(stats.leaves),
            "published_bytes": sizes["published"], "colour_bytes": sizes["colour"],
            "memory_bytes": stats.octomap_memory_bytes}


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
