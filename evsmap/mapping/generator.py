"""The ``octomap_generator`` front end that semantic_slam (floatlazer/semantic_slam) and SSMI
(ExistentialRobotics/SSMI, ``SSMI-Mapping``) share: how one RGB-D frame becomes the centroids a
semantic octree is updated with.

Both ROS nodes read their parameters into ``float`` members and pass them through ``float``
setters (``octomap_generator_ros.h``: ``float resolution_``, ``prob_hit_``, ...;
``octomap_generator.h``: ``setResolution(float)``, ``float max_range_``, ``raycast_range_``), so
OctoMap sees e.g. the resolution ``0.05f`` = 0.05000000074505806 and the hit log-odds of
``0.7f``; :func:`as_float_parameter` applies that rounding. Then, per frame
(``OctomapGenerator::insertPointCloud``):

1. the camera-frame cloud of the valid depth pixels (the semantic cloud node's), its fields
   (colour, packed class colours) filtered by PCL's ``VoxelGrid`` at the map resolution
   (:func:`evsmap.mapping.voxel_grid.voxel_grid`);
2. the centroids moved to the world frame with a ``Matrix4f`` (:func:`to_world`);
3. each centroid's distance to the sensor in ``float``; the node's own rules decide what a
   centroid within ``max_range`` updates and what is ray cast up to ``raycast_range``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from evsmap.data import Frame
from evsmap.errors import InvalidDataError

WHITE = 0xFFFFFF
"""A packed colour that is no class: both nodes' unset semantic colour (255, 255, 255)."""

FRONT_ENDS = ("generator", "direct")
"""How a frame becomes hits and misses, selectable on every semantic updater (``-o
front_end=...``): ``generator`` - the ROS nodes' ``octomap_generator`` (this module; the default
of the semantic rows of Table IV); ``direct`` - evsmap's: every valid pixel a point, OctoMap's
``insertPointCloud`` to ``max_range``, one observation per leaf and frame."""


def voc_colormap(n: int) -> np.ndarray:
    """semantic_slam's ``color_map`` (the class colours of both nodes' clouds): the PASCAL VOC
    colours of classes ``0..n-1`` (bits of the class id spread over the high bits of r, g, b),
    ``uint8`` (n, 3)."""
    ids = np.arange(int(n), dtype=np.int64)
    out = np.zeros((len(ids), 3), dtype=np.int64)
    c = ids.copy()
    for j in range(8):
        for ch in range(3):
            out[:, ch] |= ((c >> ch) & 1) << (7 - j)
        c >>= 3
    return out.astype(np.uint8)


def pack_rgb(rgb: np.ndarray) -> np.ndarray:
    """``uint32`` ``0x00RRGGBB`` of (..., 3) ``uint8`` colours (the cloud's bgr0 bytes)."""
    rgb = np.asarray(rgb).astype(np.uint32)
    packed: npt.NDArray[np.uint32] = (rgb[..., 0] << 16) | (rgb[..., 1] << 8) | rgb[..., 2]
    return packed


def unpack_rgb(packed: np.ndarray) -> np.ndarray:
    """(..., 3) ``uint8`` r, g, b of ``0x00RRGGBB`` values (``getSemanticColor``)."""
    p = np.asarray(packed).astype(np.uint32)
    return np.stack([(p >> 16) & 0xFF, (p >> 8) & 0xFF, p & 0xFF], axis=-1).astype(np.uint8)


def check_front_end(updater: str, front_end: str) -> str:
    """``front_end`` if it is one of :data:`FRONT_ENDS`.

    Raises:
        InvalidDataError: another value (one line naming the updater and the choices).
    """
    if front_end not in FRONT_ENDS:
        raise InvalidDataError(f"{updater}: front_end must be one of {', '.join(FRONT_ENDS)}; "
                               f"got {front_end!r}")
    return front_end


def as_float_parameter(value: float) -> float:
    """A parameter as the ROS node hands it to OctoMap: rounded to ``float`` (and widened back
    to ``double`` where OctoMap takes one)."""
    return float(np.float32(value))


def camera_points(frame: Frame, updater: str) -> tuple[np.ndarray, np.ndarray]:
    """(float32 camera-frame points of the valid depth pixels, their flat pixel indices): the
    semantic cloud; invalid depth is NaN in the ROS ``32FC1`` image and dropped by the filter.

    Raises:
        InvalidDataError: ``frame`` is a point cloud (the nodes build their cloud from depth).
    """
    if frame.is_cloud:
        raise InvalidDataError(f"{updater}: the octomap_generator front end builds its cloud "
                               f"from a depth image; frame {frame.name!r} is a point cloud "
                               f"(use -o front_end=direct)")
    from evsmap.geometry import backproject
    from evsmap.mapping.kernels import depth_points

    depth, intrinsics = frame.depth, frame.intrinsics
    assert depth is not None and intrinsics is not None  # an image frame (Frame's invariant)
    if depth_points is not None:
        # the compiled back-projection: the same float64 arithmetic, rounded to float32 (the
        # identity pose adds exact zeros); a frame's depth is finite (Frame's invariant)
        pixels, points = depth_points(depth, intrinsics.fx, intrinsics.fy, intrinsics.cx,
                                      intrinsics.cy, _IDENTITY)
        return points, pixels
    valid = np.isfinite(depth) & (depth > 0)
    return (backproject(depth, intrinsics, mask=valid).astype(np.float32),
            np.flatnonzero(valid))


_IDENTITY = np.eye(4)


def to_world(points: np.ndarray, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``pcl::transformPointCloud`` with a ``Matrix4f``: each coordinate summed left to right in
    ``float``; and the origin as ``point3d``."""
    m = np.asarray(pose, dtype=np.float64).astype(np.float32)
    out = np.empty_like(points)
    for a in range(3):
        out[:, a] = ((m[a, 0] * points[:, 0] + m[a, 1] * points[:, 1])
                     + m[a, 2] * points[:, 2]) + m[a, 3]
    return out, m[:3, 3].copy()


def sensor_distance(world: np.ndarray, origin: np.ndarray) -> np.ndarray:
    """``sqrt`` of the ``float`` sum of squared differences, as both nodes compute ``dist``."""
    d = world - origin
    dist: npt.NDArray[np.floating[Any]] = np.sqrt((d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1])
                                                  + d[:, 2] * d[:, 2])
    return dist
