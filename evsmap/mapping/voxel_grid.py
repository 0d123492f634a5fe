"""PCL's ``VoxelGrid<PCLPointCloud2>`` filter as semantic_slam's and SSMI's ``octomap_generator``
run it on each camera-frame cloud (PCL 1.8, ``downsample_all_data`` on, its default).

``pcl/filters/voxel_grid.cpp`` (``VoxelGrid<pcl::PCLPointCloud2>::applyFilter``):

1. The bounding box of the finite points; each point's leaf ``(floor(x * inverse_leaf) - min_b)``
   per axis in ``float``, numbered ``i + j * nx + k * nx * ny``.
2. The (leaf index, point index) pairs, in input order, sorted by leaf index with ``std::sort``
   (:func:`evsmap.mapping.stdsort.std_sort_order`: introsort, so equal leaves end up in an order
   that is deterministic but not the input order).
3. Per leaf, in that order, every float field summed in ``float`` (the ``rgb`` field through its
   r/g/b/a bytes) and divided by the count; the leaves come out in ascending leaf index.

The summation order changes the last bits of a centroid, and through them which voxel a centroid
near a border falls into and the packed class colours averaged with it.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from evsmap.mapping.stdsort import std_sort_order


@njit(cache=True, nogil=True)
def _leaf_indices(points, inverse_leaf):
    n = points.shape[0]
    lo0, lo1, lo2 = points[0, 0], points[0, 1], points[0, 2]
    hi0, hi1, hi2 = lo0, lo1, lo2
    for i in range(n):
        lo0, hi0 = min(lo0, points[i, 0]), max(hi0, points[i, 0])
        lo1, hi1 = min(lo1, points[i, 1]), max(hi1, points[i, 1])
        lo2, hi2 = min(lo2, points[i, 2]), max(hi2, points[i, 2])
    b0 = np.int64(np.floor(np.float32(lo0 * inverse_leaf)))
    b1 = np.int64(np.floor(np.float32(lo1 * inverse_leaf)))
    b2 = np.int64(np.floor(np.float32(lo2 * inverse_leaf)))
    d0 = np.int64(np.floor(np.float32(hi0 * inverse_leaf))) - b0 + 1
    d1 = np.int64(np.floor(np.float32(hi1 * inverse_leaf))) - b1 + 1
    idx = np.empty(n, np.int64)
    for i in range(n):
        i0 = np.int64(np.floor(np.float32(points[i, 0] * inverse_leaf))) - b0
        i1 = np.int64(np.floor(np.float32(points[i, 1] * inverse_leaf))) - b1
        i2 = np.int64(np.floor(np.float32(points[i, 2] * inverse_leaf))) - b2
        idx[i] = i0 + i1 * d0 + i2 * d0 * d1
    return idx


@njit(cache=True, nogil=True)
def voxel_grid(points, inverse_leaf, fields, rgb, pcl_order=True):
    """PCL ``VoxelGrid`` of float32 ``points`` (N, 3), leaf ``1 / inverse_leaf`` (float32).

    Args:
        fields: float32 (N, F) further float fields, averaged as floats (the packed class colours
            of semantic_slam's and SSMI's clouds are floats whose bits are ``0x00RRGGBB``: tiny
            denormals, whose float sum behaves like an integer sum of the packed value).
        rgb: uint8 (N, 3) colours (the ``rgb`` field: its r, g, b and a = 0 bytes averaged as
            floats and truncated).
        pcl_order: sum each leaf's points in the order PCL's ``std::sort`` leaves them (True)
            or in input order (False, evsmap's earlier reading; kept to measure the difference).

    Returns:
        ``(centroids (M, 3) float32, fields (M, F) float32, rgb (M, 3) uint8)`` in PCL's output
        order (leaf index ascending).
    """
    n = points.shape[0]
    f = fields.shape[1]
    if n == 0:
        return (np.zeros((0, 3), np.float32), np.zeros((0, f), np.float32),
                np.zeros((0, 3), np.uint8))
    idx = _leaf_indices(points, inverse_leaf)
    if pcl_order:
        order = std_sort_order(idx)
    else:
        order = np.argsort(idx, kind="mergesort")
    m = 1
    for t in range(1, n):
        if idx[order[t]] != idx[order[t - 1]]:
            m += 1
    width = 3 + f + 3
    acc = np.zeros((m, width), np.float32)
    count = np.zeros(m, np.int64)
    c = 0
    for t in range(n):
        if t > 0 and idx[order[t]] != idx[order[t - 1]]:
            c += 1
        i = order[t]
        count[c] += 1
        for a in range(3):
            acc[c, a] = np.float32(acc[c, a] + points[i, a])
        for q in range(f):
            acc[c, 3 + q] = np.float32(acc[c, 3 + q] + fields[i, q])
        for q in range(3):
            acc[c, 3 + f + q] = np.float32(acc[c, 3 + f + q] + np.float32(rgb[i, q]))
    out_p = np.empty((m, 3), np.float32)
    out_f = np.empty((m, f), np.float32)
    out_rgb = np.empty((m, 3), np.uint8)
    for j in range(m):
        cnt = np.float32(count[j])
        for a in range(3):
            out_p[j, a] = np.float32(acc[j, a] / cnt)
        for q in range(f):
            out_f[j, q] = np.float32(acc[j, 3 + q] / cnt)
        for q in range(3):
            out_rgb[j, q] = np.uint8(np.int64(np.float32(acc[j, 3 + f + q] / cnt)) & 0xFF)
    return out_p, out_f, out_rgb
