"""``octomap-cpp`` and ``octomap-color``: the real C++ OctoMap (through ``octomap-python``) as map
updaters, so the reference implementation runs in the same matrix as ours.

Both call ``insertPointCloud(points, origin, maxrange, lazy_eval=False, discretize=True)`` per
frame. ``octomap-color`` then gives every hit voxel the mean colour of the frame's points in it
with ``ColorOcTree::averageNodeColor``; the binding exposes colour one node at a time, so that
step is a Python loop over the frame's hit voxels - it belongs to the reference adapter only.
"""

from __future__ import annotations

from os import PathLike
from pathlib import Path

import numpy as np

from evsmap.data import Frame, SemanticObservation
from evsmap.fileio import atomic_write_bytes
from evsmap.geometry import transform_points
from evsmap.interfaces import MapStats, MapUpdater, PointQuery, check_file_format
from evsmap.mapping.front_end import FramePoints, compact
from evsmap.mapping.fusion.colour import mean_per_voxel
from evsmap.mapping.keys import key_to_coord, unpack
from evsmap.mapping.options import OCTREE_DEFAULTS
from evsmap.mapping.raycast import frame_points

_D = OCTREE_DEFAULTS
_SENSOR = OCTREE_DEFAULTS.sensor


class OctoMapAdapter(MapUpdater):
    """OctoMap's ``OcTree`` or ``ColorOcTree`` behind the :class:`MapUpdater` interface.

    Args:
        color: use ``ColorOcTree`` and average the points' colours per voxel.
        resolution, max_range, discretize, prob_hit, prob_miss, clamp_min, clamp_max,
        occupancy_threshold: OctoMap's parameters.
    """

    def __init__(self, *, color: bool = False, resolution: float = _D.resolution,
                 max_range: float = _D.max_range, discretize: bool = _D.discretize,
                 prob_hit: float = _SENSOR.prob_hit, prob_miss: float = _SENSOR.prob_miss,
                 clamp_min: float = _SENSOR.clamp_min, clamp_max: float = _SENSOR.clamp_max,
                 occupancy_threshold: float = _SENSOR.occupancy_threshold) -> None:
        import octomap

        self.color = color
        self.resolution = float(resolution)
        self.max_range = float(max_range)
        self.discretize = bool(discretize)
        self.tree = (octomap.ColorOcTree if color else octomap.OcTree)(self.resolution)
        self.tree.setProbHit(prob_hit)
        self.tree.setProbMiss(prob_miss)
        self.tree.setClampingThresMin(clamp_min)
        self.tree.setClampingThresMax(clamp_max)
        self.tree.setOccupancyThres(occupancy_threshold)
        self.frames = 0

    def integrate(self, frame: Frame, observation: SemanticObservation | None = None) -> None:
        if not self.color:  # only the points: OctoMap does all the rest itself
            if frame.points is not None:  # a point-cloud frame
                cloud = transform_points(frame.points, frame.pose)
                origin = frame.pose[:3, 3].copy()
            else:
                cloud, origin = frame_points(frame)
            self.tree.insertPointCloud(cloud, origin, maxrange=self.max_range,
                                       lazy_eval=False, discretize=self.discretize)
            self.frames += 1
            return
        points = FramePoints(frame, self.resolution, self.max_range, self.discretize)
        self.tree.insertPointCloud(points.points, points.origin, maxrange=self.max_range,
                                   lazy_eval=False, discretize=self.discretize)
        sel = np.flatnonzero(points.endpoint)
        used, local = compact(points.point_voxel[sel], len(points.voxel_codes))
        codes = points.voxel_codes[used]
        colors = frame.colors()
        if colors is None:  # a point cloud without colours: no colour to average
            self.frames += 1
            return
        rgb = colors[points.pixels[sel]].astype(np.float64)
        mean = np.floor(mean_per_voxel(local, rgb, len(codes))).astype(int)
        centres = key_to_coord(unpack(codes), self.resolution)
        for c, (r, g, b) in zip(centres, mean, strict=True):
            self.tree.averageNodeColor(c, int(r), int(g), int(b))
        self.frames += 1

    def stats(self) -> MapStats:
        return MapStats(nodes=int(self.tree.size()), leaves=int(self.tree.getNumLeafNodes()),
                        octomap_memory_bytes=int(self.tree.memoryUsage()))

    def occupied_voxels(self) -> int:
        return int(len(self.tree.extractPointCloud()[0]))

    def write(self, path: str | PathLike[str], file_format: str = "full") -> int:
        """OctoMap's own file (the same for ``full`` and ``published``; no ``colour``)."""
        check_file_format(self, file_format)
        path = Path(path)
        # note: writeBinary turns the live tree to maximum likelihood, as in OctoMap itself
        data = self.tree.writeBinary() if path.suffix == ".bt" else self.tree.write()
        atomic_write_bytes(path, data)
        return path.stat().st_size

    def query(self, points: np.ndarray) -> PointQuery:
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        n = len(pts)
        state = np.full(n, -1, dtype=np.int8)
        prob = np.full(n, np.nan, dtype=np.float32)
        for i, p in enumerate(pts):  # reference adapter: the binding searches one point at a time
            node = self.tree.search(p)
            try:
                occ = node.getOccupancy()
            except Exception:  # octomap.NullPointerException: unknown voxel
                continue
            prob[i] = occ
            state[i] = 1 if self.tree.isNodeOccupied(node) else 0
        return PointQuery(state=state, probability=prob, label=np.full(n, -1, dtype=np.int16))
