"""The front ends: what one frame becomes before the tree updates its nodes.

A front end is a component the updaters call, not code each re-spells:

* the **direct** front end (evsmap's, OctoMap's ``insertPointCloud``): :class:`FramePoints` - the
  frame's valid depth pixels as world points, grouped by the voxel they end in, and the rays -
  and :class:`DirectScan`, what a node type's update reads after the occupancy update (the
  frame, its points, the updated leaves, the observation);
* the **generator** front end (semantic_slam's and SSMI's ``octomap_generator``):
  :class:`GeneratorFrontEnd` - the camera-frame cloud with its float fields, PCL's
  ``VoxelGrid`` at the map resolution and the centroids moved to the world frame
  (:class:`GeneratorCloud`); each system then inserts the centroids its own way.

:class:`GroupedHits` is a frame's hits grouped by map voxel (``OctreeUpdater.endpoint_voxels``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from evsmap.data import Frame, Intrinsics, SemanticObservation
from evsmap.geometry import backproject, transform_points
from evsmap.mapping.generator import camera_points, sensor_distance, to_world
from evsmap.mapping.kernels import Kernels, depth_points, group_points
from evsmap.mapping.keys import KEY_MAX, KEY_OFFSET, pack, unpack
from evsmap.mapping.occupancy import ScanUpdate
from evsmap.mapping.raycast import octomap_keys, vector_norm

__all__ = ["DirectScan", "FramePoints", "GeneratorCloud", "GeneratorFrontEnd", "GroupedHits",
           "compact", "group_keys"]


class FramePoints:
    """A frame's valid depth pixels as world points, with the pixel attributes the updaters
    fuse (colour, semantics) in the same order, and the endpoint voxel of each point.

    Attributes:
        points: (N, 3) float64 world coordinates (computed on first use).
        origin: (3,) camera centre (sensor origin of a point-cloud frame).
        pixels: (N,) flat pixel index of each point (its index in a point-cloud frame), the
            index into :meth:`Frame.colors`.
        endpoint: (N,) bool, the point lies within the max range (its voxel is a hit).
        voxel_codes: sorted unique int64 codes of the voxels holding the points.
        point_voxel: (N,) index of each point's voxel in ``voxel_codes`` (-1: outside the map).
        rays: end points of the scan's rays (float32): the points, or with ``discretize`` the
            centres of their voxels (OctoMap's ``computeDiscreteUpdate``), computed here once.

    ``kernels`` (:data:`~evsmap.mapping.kernels.Kernels`): back-project and group the points
    with the compiled kernels (:func:`~evsmap.mapping.kernels.depth_points`,
    :func:`~evsmap.mapping.kernels.group_points`) or with numpy (:func:`octomap_keys` +
    :func:`group_keys`); the same voxels.
    """

    def __init__(self, frame: Frame, resolution: float, max_range: float,
                 discretize: bool = False, kernels: Kernels = "compiled") -> None:
        self._frame = frame
        self._points: np.ndarray | None = None
        compiled = kernels == "compiled"
        if frame.points is not None:  # a point-cloud frame
            self.pixels = np.arange(len(frame.points))
            self._points = transform_points(frame.points, frame.pose)
            pts = self._points.astype(np.float32)
        elif compiled and depth_points is not None:
            depth, i = _image(frame)
            self.pixels, pts = depth_points(depth, i.fx, i.fy, i.cx, i.cy, frame.pose)
        else:
            depth, i = _image(frame)
            valid = depth > 0
            self.pixels = np.flatnonzero(valid)
            self._points = backproject(depth, i, frame.pose, mask=valid)
            # the same float32 arithmetic as the ray casting (OctoMap's point3d)
            pts = self._points.astype(np.float32)
        self.origin = frame.pose[:3, 3].astype(np.float64)
        done = False
        if compiled and group_points is not None:
            self.point_voxel, ok, self.voxel_codes, done = group_points(
                pts, 1.0 / float(resolution), KEY_OFFSET, KEY_MAX, _DENSE_BOX)
        if not done:
            keys, ok = octomap_keys(pts, resolution)
            self.voxel_codes, inverse = group_keys(keys[ok])
            self.point_voxel = np.full(len(pts), -1, dtype=np.int64)
            self.point_voxel[ok] = inverse
        origin32 = self.origin.astype(np.float32)
        if discretize:  # the range test applies to the voxel centre the point is reduced to
            self.rays = ((unpack(self.voxel_codes) - KEY_OFFSET + 0.5) * resolution
                         ).astype(np.float32)
            inside = (vector_norm(self.rays - origin32) <= max_range if max_range >= 0
                      else np.ones(len(self.rays), dtype=bool))
            self.endpoint = ok.copy()
            self.endpoint[ok] = inside[self.point_voxel[ok]]
        else:
            self.rays = pts
            self.endpoint = (ok & (vector_norm(pts - origin32) <= max_range) if max_range >= 0
                             else ok)


    @property
    def points(self) -> np.ndarray:
        """(N, 3) float64 world coordinates of the points (computed on first use)."""
        if self._points is None:
            depth, intrinsics = _image(self._frame)
            self._points = backproject(depth, intrinsics, self._frame.pose, mask=depth > 0)
        return self._points


def _image(frame: Frame) -> tuple[np.ndarray, Intrinsics]:
    """The depth image and camera of an image frame (a frame without ``points``)."""
    assert frame.depth is not None and frame.intrinsics is not None  # an image frame
    return frame.depth, frame.intrinsics


_DENSE_BOX = 1 << 24
"""Largest key box (cells) :func:`group_keys` indexes densely instead of sorting."""


def group_keys(keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``np.unique`` of (N, 3) keys as packed codes, with the inverse: (sorted unique codes,
    position of each key among them). Inside a small box of keys (one frame's) it marks a dense
    grid instead of sorting, O(N + box)."""
    keys = np.asarray(keys, dtype=np.int64)
    if not len(keys):
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    lo = keys.min(axis=0)
    shape = keys.max(axis=0) - lo + 1
    size = int(np.prod(shape))
    if size > _DENSE_BOX:
        codes, inverse = np.unique(pack(keys), return_inverse=True)
        return codes, inverse.ravel()
    rel = keys - lo
    cell = (rel[:, 0] * shape[1] + rel[:, 1]) * shape[2] + rel[:, 2]  # same order as pack()
    mark = np.zeros(size, dtype=bool)
    mark[cell] = True
    cells = np.flatnonzero(mark)
    lut = np.empty(size, dtype=np.int64)
    lut[cells] = np.arange(len(cells))
    kz = cells % shape[2]
    kxy = cells // shape[2]
    unique = np.stack([kxy // shape[1], kxy % shape[1], kz], axis=1) + lo
    return pack(unique), lut[cell]


def compact(index: np.ndarray, size: int) -> tuple[np.ndarray, np.ndarray]:
    """``np.unique(index, return_inverse=True)`` for indices into an array of ``size`` rows,
    without sorting: (ascending unique indices, position of each input among them)."""
    present = np.zeros(size, dtype=bool)
    present[index] = True
    unique = np.flatnonzero(present)
    lut = np.cumsum(present, dtype=np.int64) - 1
    return unique, lut[index]


class GroupedHits(NamedTuple):
    """A frame's end points grouped by the map voxel they fall in.

    Attributes:
        pixels: flat pixel index of every point that ends inside the range.
        voxels: map rows of the distinct hit voxels.
        local: each point's position among ``voxels``.
    """

    pixels: np.ndarray
    voxels: np.ndarray
    local: np.ndarray


@dataclass(frozen=True)
class DirectScan:
    """One frame on the direct front end, after OctoMap's occupancy update: what a node type's
    payload update reads (:meth:`evsmap.updaters.base.OctreeUpdater.update_payload`).

    Attributes:
        frame: the frame.
        points: its points, voxels and rays.
        occupancy: the leaves the occupancy update changed (hits and misses).
        observation: the segmenter's observation (None for an updater without semantics).
    """

    frame: Frame
    points: FramePoints
    occupancy: ScanUpdate
    observation: SemanticObservation | None


VoxelGridFilter = Callable[[np.ndarray, np.float32, np.ndarray, np.ndarray],
                           tuple[np.ndarray, np.ndarray, np.ndarray]]
"""``grid(points, inverse_leaf, fields, rgb) -> (centroids, fields, rgb)``: PCL's ``VoxelGrid``
(:func:`evsmap.mapping.voxel_grid.voxel_grid`, or a compared system's own kernel)."""

CloudFields = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]
"""``fields(pixels) -> (float32 (N, F) fields, uint8 (N, 3) colours)`` of the cloud's points,
given their flat pixel indices: what a system's semantic cloud carries besides x, y, z."""


@dataclass(frozen=True)
class GeneratorCloud:
    """One frame's semantic cloud after PCL's ``VoxelGrid``, moved to the world frame.

    Attributes:
        centroids: (M, 3) ``float32`` world coordinates, in the voxel grid's order.
        origin: (3,) ``float32`` sensor origin (``point3d``).
        fields: (M, F) ``float32`` averaged float fields.
        rgb: (M, 3) ``uint8`` averaged colours.
    """

    centroids: np.ndarray
    origin: np.ndarray
    fields: np.ndarray
    rgb: np.ndarray

    def distance(self) -> np.ndarray:
        """Each centroid's distance from the origin, as both nodes compute ``dist``."""
        return sensor_distance(self.centroids, self.origin)


@dataclass(frozen=True)
class GeneratorFrontEnd:
    """The ``octomap_generator`` front end of semantic_slam and SSMI: the semantic cloud of every
    valid depth pixel (``float32`` in the camera frame) with the fields a system gives it, PCL's
    ``VoxelGrid`` at the map resolution, the centroids moved to the world frame.

    Attributes:
        updater: the updater's name, for messages.
        resolution: the leaf size (the voxel grid's leaf).
        grid: the voxel grid filter (default: :func:`evsmap.mapping.voxel_grid.voxel_grid`).
    """

    updater: str
    resolution: float
    grid: VoxelGridFilter | None = None

    def cloud(self, frame: Frame, fields: CloudFields) -> GeneratorCloud:
        """The frame's filtered cloud in the world frame.

        Raises:
            InvalidDataError: ``frame`` is a point cloud (the nodes build their cloud from depth).
        """
        cam, pixels = camera_points(frame, self.updater)
        values, rgb = fields(pixels)
        inverse = np.float32(np.float32(1.0) / np.float32(self.resolution))
        cent, averaged, cent_rgb = self._grid()(cam, inverse, values, rgb)
        world, origin = to_world(cent, frame.pose)
        return GeneratorCloud(world, origin, averaged, cent_rgb)

    def _grid(self) -> VoxelGridFilter:
        if self.grid is not None:
            return self.grid
        from evsmap.mapping.voxel_grid import voxel_grid

        grid: VoxelGridFilter = voxel_grid
        return grid
