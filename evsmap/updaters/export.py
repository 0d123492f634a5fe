"""Point-cloud export of an octree map: the centres of its occupied leaves as a binary PLY file.

:func:`occupied_points` reads any :class:`~evsmap.updaters.tree_map.OctreeMap`'s finest-level
leaves (the map is stored expanded, so a pruned block is its 8**k voxels here too) and keeps those
OctoMap calls occupied (log-odds ``>=`` the threshold's). Colour comes from the node type's
colour column (:attr:`~evsmap.mapping.node_type.NodeType.colour`: ``rgb`` for ``orgb`` and
``classic-semantic``), the label from the first slot (the most likely class) of its label column
(:attr:`~evsmap.mapping.node_type.NodeType.label`: ``classes`` for ``multiclass-bayes``,
``sem_classes`` for ``classic-semantic``).

:func:`export_ply` writes them through Open3D (``o3d.io.write_point_cloud``, binary): ``double``
x, y, z and ``uchar`` red, green, blue per vertex, coloured by the stored colour or by the label's
:func:`evsmap.classes.palette` colour (black for an occupied voxel without a class). The file is
written to a temporary name beside ``path`` and moved into place, so a failed export leaves no
partial file.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from evsmap.errors import DataFormatError, InvalidDataError
from evsmap.fileio import atomic_path, quiet_native_output
from evsmap.interfaces import OCCUPIED, MapUpdater
from evsmap.mapping.keys import key_to_coord, unpack
from evsmap.mapping.occupancy import OccupancyMap
from evsmap.updaters.tree_map import OctreeMap

__all__ = ["COLOR_BY", "check_color_by", "class_colors", "default_color_by", "export_ply",
           "occupied_points"]

COLOR_BY = ("rgb", "class")
"""Ways to colour the exported points."""

DEFAULT_PALETTE_CLASSES = 40
"""Palette size when the map holds fewer classes (NYUv2-40, the synthetic scenes' label set)."""

UNLABELLED_RGB = (0, 0, 0)
"""Colour of an occupied voxel without a class when colouring by class (void is black)."""


def _octree(updater: MapUpdater) -> OctreeMap:
    if not isinstance(updater, OctreeMap):
        raise InvalidDataError(f"PLY export needs an octree map updater (evsmap's own, e.g. orgb "
                               f"or multiclass-bayes), got {type(updater).__name__}")
    return updater


def _occupancy_map(updater: MapUpdater) -> OccupancyMap:
    return _octree(updater).leaves()


def _colour_and_label(updater: MapUpdater) -> tuple[str | None, str | None]:
    """The node type's colour and label columns (None where it has none)."""
    node_type = _octree(updater).node_type
    return node_type.colour, node_type.label


def occupied_points(updater: MapUpdater
                    ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """Centres, colours and labels of a map's occupied finest-level voxels.

    Args:
        updater: an :class:`~evsmap.updaters.tree_map.OctreeMap`.

    Returns:
        ``(centres, rgb, labels)``: ``float64`` (N, 3) voxel centres in metres (OctoMap's
        ``keyToCoord``), in the map's leaf order; ``uint8`` (N, 3) colours, or None when the map
        stores no colour; ``int16`` (N,) most likely class (-1: none yet), or None when the map
        stores no semantics.

    Raises:
        InvalidDataError: ``updater`` is not an octree updater.
    """
    m = _occupancy_map(updater)
    colour, label = _colour_and_label(updater)
    occupied = m.classify_logodds(m.logodds) == OCCUPIED
    centres = key_to_coord(unpack(m.codes[occupied]), m.resolution)
    rgb = None
    if colour is not None:
        rgb = np.ascontiguousarray(m.payload(colour)[occupied], dtype=np.uint8).reshape(-1, 3)
    labels = None
    if label is not None:
        classes = m.payload(label)[occupied]
        labels = np.asarray(classes.reshape(len(classes), -1)[:, 0], dtype=np.int16)
    return centres, rgb, labels


def default_color_by(updater: MapUpdater) -> str:
    """``"class"`` for an updater that fuses semantics, ``"rgb"`` otherwise."""
    return "class" if updater.uses_semantics else "rgb"


def check_color_by(updater: MapUpdater, color_by: str | None = None) -> str:
    """The colouring :func:`export_ply` will use for ``updater`` (``color_by``, or
    :func:`default_color_by` when None), checked before any mapping work is done.

    Raises:
        InvalidDataError: not an octree updater, an unknown ``color_by``, or a map that does not
            store what it asks for (colours for ``"rgb"``, classes for ``"class"``).
    """
    colour, label = _colour_and_label(updater)
    if color_by is None:
        color_by = default_color_by(updater)
    if color_by not in COLOR_BY:
        raise InvalidDataError(f"unknown PLY colouring {color_by!r} (known: "
                               f"{', '.join(COLOR_BY)})")
    name = _octree(updater).name or type(updater).__name__
    if color_by == "rgb" and colour is None:
        raise InvalidDataError(f"map updater {name!r} stores no colours: export it coloured by "
                               "class (--ply-color class; color_by='class' in Python)")
    if color_by == "class" and label is None:
        raise InvalidDataError(f"map updater {name!r} stores no classes: export it with its "
                               "colours (--ply-color rgb; color_by='rgb' in Python)")
    return color_by


def class_colors(labels: np.ndarray) -> np.ndarray:
    """``uint8`` (N, 3) palette colours of ``labels`` (black where a label is negative)."""
    from evsmap.classes import palette

    labels = np.asarray(labels).astype(np.int64)
    top = int(labels.max()) + 1 if labels.size else 0
    table = palette(max(top, DEFAULT_PALETTE_CLASSES))
    out = np.empty((len(labels), 3), dtype=np.uint8)
    known = labels >= 0
    out[known] = table[labels[known]]
    out[~known] = UNLABELLED_RGB
    return out


def export_ply(updater: MapUpdater, path: str | os.PathLike[str], *,
               color_by: str | None = None) -> int:
    """Write the map's occupied voxel centres as a binary PLY point cloud (Open3D).

    Args:
        updater: an :class:`~evsmap.updaters.tree_map.OctreeMap`.
        path: the file to write (replaced if it exists); always PLY, whatever its suffix.
        color_by: ``"rgb"`` (the stored colours) or ``"class"`` (the palette colour of each
            voxel's most likely class); default :func:`default_color_by`.

    Returns:
        The number of points written.

    Raises:
        InvalidDataError: unknown ``color_by``, a map without the colours or classes asked for,
            or a map without occupied voxels.
        DataFormatError: ``path`` cannot be written.
    """
    color_by = check_color_by(updater, color_by)
    centres, rgb, labels = occupied_points(updater)
    if color_by == "rgb":
        assert rgb is not None  # check_color_by: the map stores colours
        colors = rgb
    else:
        assert labels is not None  # check_color_by: the map stores classes
        colors = class_colors(labels)
    if not len(centres):
        raise InvalidDataError(f"{path}: the map has no occupied voxels, nothing to export")
    _write_point_cloud(Path(path), centres, colors)
    return int(len(centres))


def _write_point_cloud(path: Path, points: np.ndarray, colors: np.ndarray) -> None:
    """Binary PLY through Open3D, atomically (temporary ``.ply`` beside ``path``, then rename)."""
    from evsmap.open3d_loader import load_open3d

    o3d = load_open3d()

    folder = path.parent
    if path.is_dir():
        raise DataFormatError(f"cannot write {path}: it is a folder")
    cloud = o3d.geometry.PointCloud()
    cloud.points = o3d.utility.Vector3dVector(np.ascontiguousarray(points, dtype=np.float64))
    cloud.colors = o3d.utility.Vector3dVector(np.asarray(colors, dtype=np.float64) / 255.0)
    try:
        with atomic_path(path, suffix=".ply") as tmp:  # Open3D picks the format by extension
            # Open3D reports a failure itself (a warning, or past Python's streams): quiet
            with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error), \
                    quiet_native_output():
                ok = o3d.io.write_point_cloud(str(tmp), cloud, write_ascii=False)
            if not ok:
                raise DataFormatError(f"cannot write {path}: Open3D could not write the point "
                                      f"cloud (is {folder} writable?)")
    except OSError as e:
        raise DataFormatError(f"cannot write {path}: {e.strerror or e}") from e
