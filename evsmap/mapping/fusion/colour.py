"""Colour fusion rules of OctoMap's ``ColorOcTree``, vectorised over M voxels.

* :func:`integrate_color` - ``ColorOcTree::integrateNodeColor``: with the node's occupancy
  probability p, each channel becomes ``(uint8)(prev * p + new * (0.99 - p))`` (C++ cast:
  truncation), or the new colour when the node had none.
* :func:`average_node_color` - ``averageNodeColor`` (what semantic_slam uses for leaves):
  ``(prev + new) / 2`` in integer arithmetic.
* :func:`average_color` - ``getAverageChildColor`` for inner nodes: integer mean over the children
  that have a colour, white (255, 255, 255) when none has.
* OctoMap's convention is that a colour is "set" when it is not pure white (:func:`color_is_set`).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

WHITE = 255


def color_is_set(rgb: np.ndarray) -> np.ndarray:
    """OctoMap's ``isColorSet``: any channel differs from 255 (pure white means "no colour")."""
    is_set: npt.NDArray[np.bool_] = np.any(np.asarray(rgb) != WHITE, axis=-1)
    return is_set


def integrate_color(prev_rgb: np.ndarray, prev_set: np.ndarray, occupancy: np.ndarray,
                    new_rgb: np.ndarray) -> np.ndarray:
    """``ColorOcTree::integrateNodeColor`` for M voxels.

    Args:
        prev_rgb: ``uint8`` (M, 3) current colours.
        prev_set: bool (M,) whether a colour was set (see :func:`color_is_set`).
        occupancy: (M,) occupancy probability of each node (``getOccupancy``).
        new_rgb: (M, 3) observed colours.

    Returns:
        ``uint8`` (M, 3): ``trunc(prev * p + new * (0.99 - p))`` per channel where a colour was
        set, else ``new_rgb``. Values are clipped to [0, 255] (C++ leaves p > 0.99 undefined).
    """
    prev = np.asarray(prev_rgb, dtype=np.float64)
    new = np.asarray(new_rgb)
    p = np.asarray(occupancy, dtype=np.float64)[:, None]
    mixed = np.trunc(prev * p + new.astype(np.float64) * (0.99 - p))
    mixed = np.clip(mixed, 0, 255).astype(np.uint8)
    return np.where(np.asarray(prev_set, dtype=bool)[:, None], mixed, new.astype(np.uint8))


def average_node_color(prev_rgb: np.ndarray, prev_set: np.ndarray,
                       new_rgb: np.ndarray) -> np.ndarray:
    """``averageNodeColor``: ``(prev + new) / 2`` (integer division) where a colour was set,
    else the new colour; ``uint8`` (M, 3)."""
    prev = np.asarray(prev_rgb).astype(np.int32)
    new = np.asarray(new_rgb).astype(np.int32)
    mean = ((prev + new) // 2).astype(np.uint8)
    return np.where(np.asarray(prev_set, dtype=bool)[:, None], mean, new.astype(np.uint8))


def average_color(children_rgb: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """``getAverageChildColor`` for M inner nodes.

    Args:
        children_rgb: ``uint8`` (M, n, 3) colours of up to n (8) children.
        mask: bool (M, n) children that exist and have a colour set.

    Returns:
        ``uint8`` (M, 3): per channel ``sum // count`` over the masked children (C++ int
        division), white where no child counts.
    """
    rgb = np.asarray(children_rgb).astype(np.int64)
    m = np.asarray(mask, dtype=bool)
    sums = np.where(m[..., None], rgb, 0).sum(axis=1)
    count = m.sum(axis=1)
    mean = sums // np.maximum(count, 1)[:, None]
    return np.where((count > 0)[:, None], mean, WHITE).astype(np.uint8)



def mean_per_voxel(voxel: np.ndarray, values: np.ndarray, n_voxels: int) -> np.ndarray:
    """Mean of ``values`` (P, c) over the points of each voxel (``voxel``: (P,) in [0, n))."""
    counts = np.bincount(voxel, minlength=n_voxels).astype(np.float64)
    out = np.stack([np.bincount(voxel, weights=values[:, j], minlength=n_voxels)
                    for j in range(values.shape[1])], axis=1)
    return out / np.maximum(counts, 1)[:, None]


def average_frame_colours(stored: np.ndarray, colors: np.ndarray | None, pixels: np.ndarray,
                          voxels: np.ndarray, local: np.ndarray) -> None:
    """``averageNodeColor`` of each hit voxel's stored colour and the mean colour of the frame's
    points in it, in place.

    Args:
        stored: ``uint8`` (N, 3) colours of the map's leaves (changed in place).
        colors: the frame's (P, 3) colours by flat pixel index, or None (a point cloud without
            colours: OctoMap leaves the colour unset).
        pixels: flat pixel index of every point that ends inside the range.
        voxels: the map rows of the distinct hit voxels.
        local: each point's position among ``voxels``.
    """
    if colors is None:
        return
    rgb = colors[pixels].astype(np.float64)
    mean = np.floor(mean_per_voxel(local, rgb, len(voxels))).astype(np.uint8)
    prev = stored[voxels]
    stored[voxels] = average_node_color(prev, color_is_set(prev), mean)
