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
    ``coordToKeyChecked``), a mask of the points inside the key range, and - when the keys' box
    holds at most ``dense_limit`` cells - the sorted unique packed codes and each valid point's
    position among them (a dense mark over the box, no sort). Returns ``(keys, ok, codes,
    inverse, done)``; ``done`` is False when the box is too large (the caller sorts instead)."""
    n = points.shape[0]
    keys = np.zeros((n, 3), dtype=np.int64)
    ok = np.ones(n, dtype=np.bool_)
    lo = np.full(3, key_max + 1, dtype=np.int64)
    hi = np.full(3, -1, dtype=np.int64)
    count = 0
    for i in range(n):
        inside = True
        for a in range(3):
            s = np.floor(np.float64(points[i, a]) * rf)
            if not (s >= -offset and s <= key_max - offset):  # also NaN and inf
                inside = False
                break
            keys[i, a] = np.int64(s) + offset
        if not inside:
            ok[i] = False
            keys[i, 0] = 0
            keys[i, 1] = 0
            keys[i, 2] = 0
            continue
        count += 1
        for a in range(3):
            if keys[i, a] < lo[a]:
                lo[a] = keys[i, a]
            if keys[i, a] > hi[a]:
                hi[a] = keys[i, a]
    empty = np.zeros(0, dtype=np.int64)
    if count == 0:
        return keys, ok, empty, empty, True
    s0, s1, s2 = hi[0] - lo[0] + 1, hi[1] - lo[1] + 1, hi[2] - lo[2] + 1
    if s0 * s1 * s2 > dense_limit:
        return keys, ok, empty, empty, False
    mark = np.zeros(s0 * s1 * s2, dtype=np.bool_)
    lut = np.empty(s0 * s1 * s2, dtype=np.int64)  # written (and read) at marked cells only
    cells = np.empty(count, dtype=np.int64)
    j = 0
    for i in range(n):
        if ok[i]:
            c = ((keys[i, 0] - lo[0]) * s1 + (keys[i, 1] - lo[1])) * s2 + (keys[i, 2] - lo[2])
            cells[j] = c
            mark[c] = True
            j += 1
    unique = 0
    for c in range(mark.size):  # box order = packed-code order
        if mark[c]:
            lut[c] = unique
            unique += 1
    codes = np.empty(unique, dtype=np.int64)
    inverse = np.empty(count, dtype=np.int64)
    for j in range(count):
        c = cells[j]
        u = lut[c]
        inverse[j] = u
        kz = c % s2
        kxy = c // s2
        codes[u] = ((kxy // s1 + lo[0]) << 32) | ((kxy % s1 + lo[1]) << 16) | (kz + lo[2])
    return keys, ok, codes, inverse, True


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
    ``created`` (2-D arrays; 1-D ones as one column)."""
    j = 0
    src = 0
    n_new = created.shape[0]
    per_row = fill.shape[0] > 1
    for dst in range(out.shape[0]):
        if j < n_new and created[j] == dst:
            f = j if per_row else 0
            for c in range(out.shape[1]):
                out[dst, c] = fill[f, c]
            j += 1
        else:
            for c in range(out.shape[1]):
                out[dst, c] = old[src, c]
            src += 1


if numba is not None:
    trace = numba.njit(cache=True, nogil=True)(_trace)
    group_points = numba.njit(cache=True, nogil=True)(_group_points)
    grow_rows = numba.njit(cache=True, nogil=True)(_grow_rows)
    depth_points = numba.njit(cache=True, nogil=True)(_depth_points)
else:  # pragma: no cover
    trace = group_points = grow_rows = depth_points = None
