"""Compiled kernels (numba) for the two per-point and per-ray loops of map updating.

* :func:`trace` - 3D DDA (OctoMap's ``computeRayKeys``), one ray at a time in machine code.
* :func:`group_points` - OctoMap keys of a frame's points and their grouping by voxel.
* :func:`grow_rows` - the sorted leaf arrays with the rows of new leaves inserted.
* :func:`depth_points` - a depth image's valid pixels as float32 world points.
* :func:`grid_codes` - the packed codes of a dense grid's marked cells, in order.
* :func:`sorted_index` - ``np.searchsorted`` of codes in the map's sorted codes, and a hit mask.

The kernels split their loops over threads (numba ``prange``, as many as
:func:`evsmap.mapping.threads.update_threads` gives the caller) so that every thread writes its
own slices of the outputs - points, rays, grid blocks, voxels - or the same value (``True``) to
a shared mark: the results are the same at any number of threads. Work that has to be numbered
in order (a grid's marked cells, a depth image's valid pixels) is counted per block in parallel,
numbered with a prefix sum over the blocks, then written per block.

Each has a pure-numpy counterpart (:func:`evsmap.mapping.raycast._ray_keys`'s merge,
:func:`evsmap.mapping.front_end.group_keys`, ``np.searchsorted`` ...) that computes the same
results; the tests compare them.

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
from types import ModuleType
from typing import Literal

import numpy as np

from evsmap.errors import InvalidDataError
from evsmap.mapping import threads  # noqa: F401 - chooses numba's threading layer first

numba: ModuleType | None
try:
    import numba
except ImportError:  # pragma: no cover - numba is a dependency; the numpy path still works
    numba = None
prange = numba.prange if numba is not None else range

Kernels = Literal["compiled", "reference"]
"""Which code runs the map-update loops: ``"compiled"`` - the numba kernels of this module and
of the updaters (the default; the numpy code where numba cannot be imported) - or
``"reference"`` - the numpy code the tests compare them with. The results are the same."""

KERNELS: tuple[Kernels, ...] = ("compiled", "reference")


def check_kernels(kernels: str) -> Kernels:
    """``kernels`` if it is one of :data:`KERNELS`.

    Raises:
        InvalidDataError: any other value.
    """
    if kernels == "compiled":
        return "compiled"
    if kernels == "reference":
        return "reference"
    raise InvalidDataError(f"kernels must be one of {', '.join(KERNELS)}, got {kernels!r}")


_BLOCK = 1 << 16
"""Cells (or rows) per block of the block-numbered passes."""


def blocks(n: int, size: int) -> int:
    """Number of blocks of ``size`` covering ``n`` items."""
    return (n + size - 1) // size


def _walk(r, tmax, tdelta, bound, length, increments, end_offset, origin_index, grid, out, n):
    """Walk ray ``r``: mark the voxels it enters in ``grid`` (when it is not empty) or write
    their linear indices to ``out`` from position ``n``. Returns the next free position."""
    use_grid = grid.size > 0
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


def _trace(tmax, tdelta, bound, length, increments, end_offset, origin_index, grid, out):
    """Walk every ray; mark the voxels entered in ``grid`` (when it is not empty) or append their
    linear indices to ``out``. ``bound`` caps each ray's steps (a safety net: the rounding guard
    stops a ray before it). Returns the number of indices written to ``out``. With a grid the
    rays are walked in parallel (every mark stores ``True``); the list is written in ray order
    by one thread."""
    if grid.size > 0:
        for r in prange(tmax.shape[0]):
            _walk(r, tmax, tdelta, bound, length, increments, end_offset, origin_index, grid,
                  out, 0)
        return 0
    n = 0
    for r in range(tmax.shape[0]):
        n = _walk(r, tmax, tdelta, bound, length, increments, end_offset, origin_index, grid,
                  out, n)
    return n


def _prefix(counts):
    """Exclusive prefix sum (``len(counts) + 1`` entries, the total last)."""
    start = np.zeros(counts.shape[0] + 1, dtype=np.int64)
    for b in range(counts.shape[0]):
        start[b + 1] = start[b] + counts[b]
    return start


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
    # pass 1, per block of points: the range test and the keys' box (nothing else is stored: a
    # second pass recomputes the keys, cheaper than writing and reading them back)
    nb = blocks(n, _BLOCK)
    box = np.empty((nb, 6), dtype=np.int64)
    for b in prange(nb):
        lo0 = lo1 = lo2 = key_max + 1
        hi0 = hi1 = hi2 = -1
        for i in range(b * _BLOCK, min(n, (b + 1) * _BLOCK)):
            s0 = math.floor(np.float64(points[i, 0]) * rf)
            s1 = math.floor(np.float64(points[i, 1]) * rf)
            s2 = math.floor(np.float64(points[i, 2]) * rf)
            # comparisons that are False for NaN as well
            if (s0 >= lim_lo) & (s0 <= lim_hi) & (s1 >= lim_lo) & (s1 <= lim_hi) \
                    & (s2 >= lim_lo) & (s2 <= lim_hi):
                ok[i] = True
                k0 = np.int64(s0) + offset
                k1 = np.int64(s1) + offset
                k2 = np.int64(s2) + offset
                lo0, lo1, lo2 = min(lo0, k0), min(lo1, k1), min(lo2, k2)
                hi0, hi1, hi2 = max(hi0, k0), max(hi1, k1), max(hi2, k2)
        box[b, 0], box[b, 1], box[b, 2] = lo0, lo1, lo2
        box[b, 3], box[b, 4], box[b, 5] = hi0, hi1, hi2
    lo0 = lo1 = lo2 = key_max + 1
    hi0 = hi1 = hi2 = -1
    for b in range(nb):
        lo0, lo1, lo2 = min(lo0, box[b, 0]), min(lo1, box[b, 1]), min(lo2, box[b, 2])
        hi0, hi1, hi2 = max(hi0, box[b, 3]), max(hi1, box[b, 4]), max(hi2, box[b, 5])
    point_voxel = np.full(n, -1, dtype=np.int64)
    empty = np.zeros(0, dtype=np.int64)
    if hi0 < 0:  # no point inside
        return point_voxel, ok, empty, True
    b0, b1, b2 = hi0 - lo0 + 1, hi1 - lo1 + 1, hi2 - lo2 + 1
    size = b0 * b1 * b2
    if size > dense_limit:
        return point_voxel, ok, empty, False
    # pass 2: each point's cell in the box (kept in point_voxel for now), marked in the table
    table = np.zeros(size, dtype=np.int32)
    for i in prange(n):
        if ok[i]:
            c = (((np.int64(math.floor(np.float64(points[i, 0]) * rf)) + offset - lo0) * b1
                  + (np.int64(math.floor(np.float64(points[i, 1]) * rf)) + offset - lo1)) * b2
                 + (np.int64(math.floor(np.float64(points[i, 2]) * rf)) + offset - lo2))
            point_voxel[i] = c
            table[c] = 1
    # box order is packed-code order: number the marked cells (per block, then a prefix sum
    # over the blocks), decode each once
    nc = blocks(size, _BLOCK)
    marked = np.zeros(nc, dtype=np.int64)
    for b in prange(nc):
        m = 0
        for c in range(b * _BLOCK, min(size, (b + 1) * _BLOCK)):
            m += table[c]
        marked[b] = m
    start = _prefix(marked)
    codes = np.empty(start[nc], dtype=np.int64)
    for b in prange(nc):
        u = start[b]
        for c in range(b * _BLOCK, min(size, (b + 1) * _BLOCK)):
            if table[c]:
                u += 1
                table[c] = u
                kz = c % b2
                kxy = c // b2
                codes[u - 1] = ((kxy // b1 + lo0) << 32) | ((kxy % b1 + lo1) << 16) | (kz + lo2)
    for i in prange(n):
        if ok[i]:
            point_voxel[i] = table[point_voxel[i]] - 1
    return point_voxel, ok, codes, True


def _depth_points(depth, fx, fy, cx, cy, pose):
    """The valid pixels of a depth image (flat indices, row-major) and their world points rounded
    to float32, with exactly :func:`evsmap.geometry.backproject`'s float64 arithmetic. Rows are
    counted, then written, in parallel."""
    h, w = depth.shape
    valid = np.zeros(h, dtype=np.int64)
    for v in prange(h):
        m = 0
        for u in range(w):
            if depth[v, u] > 0:
                m += 1
        valid[v] = m
    start = _prefix(valid)
    n = start[h]
    pixels = np.empty(n, dtype=np.int64)
    points = np.empty((n, 3), dtype=np.float32)
    for v in prange(h):
        i = start[v]
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
    new rows) as block copies, the slabs in parallel: slab ``j`` ends at ``created[j]`` and
    starts ``j`` rows further in ``out`` than in ``old``."""
    n_new = created.shape[0]
    per_row = fill.shape[0] > 1
    for jj in prange(n_new + 1):
        j = np.int64(jj)
        begin = created[j - 1] + 1 if j > 0 else np.int64(0)
        stop = created[j] if j < n_new else np.int64(out.shape[0])
        if stop > begin:
            out[begin:stop] = old[begin - j:stop - j]
        if j < n_new:
            out[stop] = fill[j if per_row else np.int64(0)]
    return None


def _grid_codes(grid, base0, base1, base2, shape1, shape2):
    """Packed codes ``(k0 << 32) | (k1 << 16) | k2`` of a dense grid's marked cells in index
    order (cell ``((k0 - base0) * shape1 + (k1 - base1)) * shape2 + (k2 - base2)``): blocks of
    rows (fixed ``k0``, ``k1``) counted, then written, in parallel."""
    rows = grid.shape[0] // shape2
    per = max(1, _BLOCK // shape2)
    nb = blocks(rows, per)
    marked = np.zeros(nb, dtype=np.int64)
    for b in prange(nb):
        m = 0
        for c in range(b * per * shape2, min(rows, (b + 1) * per) * shape2):
            m += grid[c]
        marked[b] = m
    start = _prefix(marked)
    codes = np.empty(start[nb], dtype=np.int64)
    for b in prange(nb):
        u = start[b]
        for r in range(b * per, min(rows, (b + 1) * per)):
            k0 = r // shape1
            head = ((k0 + base0) << 32) | ((r - k0 * shape1 + base1) << 16)
            for k2 in range(shape2):
                if grid[r * shape2 + k2]:
                    codes[u] = head | (k2 + base2)
                    u += 1
    return codes


def _sorted_index(sorted_codes, queries):
    """``np.searchsorted(sorted_codes, queries)`` (side ``left``) and the mask of the queries
    found there. The queries are split in blocks searched in parallel; within a block, a query
    not below the previous one gallops on from the previous position (the queries are usually
    sorted, and close together), any other starts a binary search over the whole array."""
    m = sorted_codes.shape[0]
    n = queries.shape[0]
    pos = np.empty(n, dtype=np.int64)
    found = np.zeros(n, dtype=np.bool_)
    nb = blocks(n, _BLOCK // 8)
    for b in prange(nb):
        lo = 0
        for i in range(b * (_BLOCK // 8), min(n, (b + 1) * (_BLOCK // 8))):
            q = queries[i]
            if i == b * (_BLOCK // 8) or q < queries[i - 1]:
                lo = 0
            # every code below lo is < q; gallop to a hi with hi == m or code[hi] >= q
            hi = lo
            step = 1
            while hi < m and sorted_codes[hi] < q:
                lo = hi + 1
                hi += step
                step *= 2
            if hi > m:
                hi = m
            while lo < hi:
                mid = (lo + hi) >> 1
                if sorted_codes[mid] < q:
                    lo = mid + 1
                else:
                    hi = mid
            pos[i] = lo
            found[i] = lo < m and sorted_codes[lo] == q
    return pos, found


if numba is not None:
    _serial = {"cache": True, "nogil": True}
    _parallel = {"cache": True, "nogil": True, "parallel": True}
    blocks = numba.njit(**_serial)(blocks)
    _prefix = numba.njit(**_serial)(_prefix)
    _walk = numba.njit(**_serial)(_walk)
    trace = numba.njit(**_parallel)(_trace)
    group_points = numba.njit(**_parallel)(_group_points)
    grow_rows = numba.njit(**_parallel)(_grow_rows)
    depth_points = numba.njit(**_parallel)(_depth_points)
    grid_codes = numba.njit(**_parallel)(_grid_codes)
    sorted_index = numba.njit(**_parallel)(_sorted_index)
else:  # pragma: no cover
    trace = group_points = grow_rows = depth_points = grid_codes = sorted_index = None
