"""Compiled kernels (numba) for the two per-point and per-ray loops of map updating.

* :func:`trace` - 3D DDA (OctoMap's ``computeRayKeys``), one ray at a time in machine code.
* :func:`group_points` - OctoMap keys of a frame's points and their grouping by voxel.
* :func:`grow_rows` - the sorted leaf arrays with the rows of new leaves inserted.
* :func:`depth_points` - a depth image's valid pixels as float32 world points.

Both have pure-numpy counterparts (:func:`evsmap.mapping.raycast._ray_keys`'s merge and
:func:`evsmap.updaters.base.group_keys`) that compute the same results; the tests compare them.

The DDA kernel runs the exact loop of ``OcTreeBaseImpl::computeRayKeys`` from per-ray start values
that :func:`evsmap.mapping.raycast._ray_keys` computes with OctoMap's float/double arithmetic:
step to the axis whose ``tMax`` is smallest (``if (tMax[0] < tMax[1]) ... else ...``, so ties go
to the highest axis), ``tMax += tDelta`` in double, stop on entering the end voxel or when
``min(tMax) > length``. Every voxel entered is marked in a dense bool grid over the scan's
bounding box (linear index ``sum((key - base) * strides)``), or written to a buffer when the box
is too large for a grid. The pure-numpy merge in :mod:`evsmap.mapping.raycast` computes the same
sets and is the reference the tests compare this kernel with.
"""

from __future__ import annotations

import math

import numpy as np

try:
    import numba
except ImportError:  # pragma: no cover - numba is a dependency; the numpy path still works
    numba = None


def _trace(tmax, tdelta, bound, length, increments, end_offset, origin_index, grid, out):
    """Walk every ray; mark the voxels entered in ``grid`` (when it is not empty) or append their
    linear indices to ``out``. ``bound`` caps each ray's steps (a safety net: the rounding guard
    stops a ray before it). Returns the number of indices written to ``out``."""
    n = 0
    use_grid = grid.size > 0
    for r in range(tmax.shape[0]):
        t0, t1, t2 = tmax[r, 0], tmax[r, 1], tmax[r, 2]
        d0, d1, d2 = tdelta[r, 0], tdelta[r, 1], tdelta[r, 2]
        i0, i1, i2 = increments[r, 0], increments[r, 1], increments[r, 2]
        limit = length[r]
        target = end_offset[r]
        guard = bound[r]
        offset = 0
        while True:
            if t0 < t1:
                if t0 < t2:
                    offset += i0
                    t0 += d0
                else:
                    offset += i2
                    t2 += d2
            elif t1 < t2:
                offset += i1
                t1 += d1
            else:
                offset += i2
                t2 += d2
            if offset == target:
                break
            tmin = min(t0, min(t1, t2))
            if tmin > limit:
                break
            guard -= 1
            if guard < 0:
                break
            if use_grid:
                grid[origin_index + offset] = True
            else:
                out[n] = origin_index + offset
                n += 1
    return n


def _group_points(points, rf, offset, key_max, dense_limit):
    """Keys ``floor(float64(p) * rf) + offset`` of float32 ``points`` (OctoMap's
    ``coordToKeyChecked``) grouped by voxel: ``(point_voxel, ok, codes, done)`` - each point's
    position among the sorted unique packed ``codes`` (-1 outside the key range), the mask of the
    points inside. Only when the keys' box holds at most ``dense_limit`` cells (a dense mark over
    the box, no sort); otherwise ``done`` is False and the caller sorts instead."""
    n = points.shape[0]
    lim_lo = -offset
    lim_hi = key_max - offset
    ok = np.zeros(n, dtype=np.bool_)
    lo0 = lo1 = lo2 = key_max + 1
    hi0 = hi1 = hi2 = -1
    count = 0
    # pass 1: the range test and the keys' box (nothing else is stored: a second pass recomputes
    # the keys, cheaper than writing and reading them back)
    for i in range(n):
        s0 = math.floor(np.float64(points[i, 0]) * rf)
        s1 = math.floor(np.float64(points[i, 1]) * rf)
        s2 = math.floor(np.float64(points[i, 2]) * rf)
        # comparisons that are False for NaN as well
        if (s0 >= lim_lo) & (s0 <= lim_hi) & (s1 >= lim_lo) & (s1 <= lim_hi) \
                & (s2 >= lim_lo) & (s2 <= lim_hi):
            ok[i] = True
            count += 1
            k0 = np.int64(s0) + offset
            k1 = np.int64(s1) + offset
            k2 = np.int64(s2) + offset
            lo0, lo1, lo2 = min(lo0, k0), min(lo1, k1), min(lo2, k2)
            hi0, hi1, hi2 = max(hi0, k0), max(hi1, k1), max(hi2, k2)
    point_voxel = np.full(n, -1, dtype=np.int64)
    empty = np.zeros(0, dtype=np.int64)
    if count == 0:
        return point_voxel, ok, empty, True
    b0, b1, b2 = hi0 - lo0 + 1, hi1 - lo1 + 1, hi2 - lo2 + 1
    size = b0 * b1 * b2
    if size > dense_limit:
        return point_voxel, ok, empty, False
    # pass 2: each point's cell in the box (kept in point_voxel for now), marked in the table
    table = np.zeros(size, dtype=np.int32)
    for i in range(n):
        if ok[i]:
            c = (((np.int64(math.floor(np.float64(points[i, 0]) * rf)) + offset - lo0) * b1
                  + (np.int64(math.floor(np.float64(points[i, 1]) * rf)) + offset - lo1)) * b2
                 + (np.int64(math.floor(np.float64(points[i, 2]) * rf)) + offset - lo2))
            point_voxel[i] = c
            table[c] = 1
    # box order is packed-code order: number the marked cells, decode each once
    unique = 0
    for c in range(size):
        if table[c]:
            unique += 1
    codes = np.empty(unique, dtype=np.int64)
    u = 0
    for c in range(size):
        if table[c]:
            u += 1
            table[c] = u
            kz = c % b2
            kxy = c // b2
            codes[u - 1] = ((kxy // b1 + lo0) << 32) | ((kxy % b1 + lo1) << 16) | (kz + lo2)
    for i in range(n):
        if ok[i]:
            point_voxel[i] = table[point_voxel[i]] - 1
    return point_voxel, ok, codes, True


def _depth_points(depth, fx, fy, cx, cy, pose):
    """The valid pixels of a depth image (flat indices, row-major) and their world points rounded
    to float32, with exactly :func:`evsmap.geometry.backproject`'s float64 arithmetic."""
    h, w = depth.shape
    n = 0
    for v in range(h):
        for u in range(w):
            if depth[v, u] > 0:
                n += 1
    pixels = np.empty(n, dtype=np.int64)
    points = np.empty((n, 3), dtype=np.float32)
    i = 0
    for v in range(h):
        for u in range(w):
            d = depth[v, u]
            if d > 0:
                z = np.float64(d)
                x = (np.float64(u) - cx) / fx * z
                y = (np.float64(v) - cy) / fy * z
                for a in range(3):
                    points[i, a] = np.float32(
                        pose[a, 0] * x + pose[a, 1] * y + pose[a, 2] * z + pose[a, 3])
                pixels[i] = v * w + u
                i += 1
    return pixels, points


def _grow_rows(old, created, fill, out):
    """``out`` (rows = rows of ``old`` + len(``created``)): the rows of ``old`` in order, with
    the rows of ``fill`` (one per new row, or a single row for all) at the sorted row positions
    ``created`` (2-D arrays; 1-D ones as one column). The old rows move in slabs (between two
    new rows) as block copies."""
    n_new = created.shape[0]
    per_row = fill.shape[0] > 1
    src = 0
    dst = 0
    for j in range(n_new + 1):
        stop = created[j] if j < n_new else out.shape[0]
        run = stop - dst
        if run > 0:
            out[dst:stop] = old[src:src + run]
            src += run
        if j < n_new:
            out[stop] = fill[j if per_row else 0]
            dst = stop + 1
    return None


if numba is not None:
    trace = numba.njit(cache=True, nogil=True)(_trace)
    group_points = numba.njit(cache=True, nogil=True)(_group_points)
    grow_rows = numba.njit(cache=True, nogil=True)(_grow_rows)
    depth_points = numba.njit(cache=True, nogil=True)(_depth_points)
else:  # pragma: no cover
    trace = group_points = grow_rows = depth_points = None
