"""libstdc++'s ``std::sort`` as a permutation, for ports that depend on the order it leaves equal
elements in.

``std::sort`` is not stable, but it is deterministic: for a given input its introsort (quicksort
with a median-of-three pivot moved to the front, depth limit ``2 * floor(log2 n)`` with heapsort
beyond it, ranges of at most 16 left to a final insertion sort) always leaves equal keys in the
same order. PCL's ``VoxelGrid`` sorts its (leaf index, point index) pairs by leaf index with it
and sums each leaf's points in that order, so the last bits of every centroid depend on it
(``pcl/filters/voxel_grid.cpp``, ``std::sort(index_vector.begin(), index_vector.end(),
std::less<cloud_point_index_idx>())``).

:func:`std_sort_order` follows ``bits/stl_algo.h`` and ``bits/stl_heap.h`` of GCC 5 and later
(``__introsort_loop``, ``__move_median_to_first``, ``__unguarded_partition``,
``__final_insertion_sort``, ``__partial_sort``); ``tests/mapping/test_stdsort.py`` checks it
against the orders a compiled ``std::sort`` produced.
"""

from __future__ import annotations

import numpy as np
from numba import njit

THRESHOLD = 16
"""``_S_threshold``: ranges this short are left to the final insertion sort."""


# The sorted elements are (key, index) pairs held in two arrays ``k`` and ``p`` moved together,
# so comparisons read ``k`` in place (as std::sort reads its elements) rather than through ``p``.
@njit(cache=True, nogil=True)
def _swap(k, p, a, b):
    tk = k[a]
    k[a] = k[b]
    k[b] = tk
    tp = p[a]
    p[a] = p[b]
    p[b] = tp


@njit(cache=True, nogil=True)
def _move_median_to_first(k, p, result, a, b, c):
    if k[a] < k[b]:
        if k[b] < k[c]:
            _swap(k, p, result, b)
        elif k[a] < k[c]:
            _swap(k, p, result, c)
        else:
            _swap(k, p, result, a)
    elif k[a] < k[c]:
        _swap(k, p, result, a)
    elif k[b] < k[c]:
        _swap(k, p, result, c)
    else:
        _swap(k, p, result, b)


@njit(cache=True, nogil=True)
def _unguarded_partition(k, p, first, last, pivot):
    while True:
        while k[first] < k[pivot]:
            first += 1
        last -= 1
        while k[pivot] < k[last]:
            last -= 1
        if not first < last:
            return first
        _swap(k, p, first, last)
        first += 1


@njit(cache=True, nogil=True)
def _push_heap(k, p, first, hole, top, vk, vp):
    parent = (hole - 1) // 2
    while hole > top and k[first + parent] < vk:
        k[first + hole] = k[first + parent]
        p[first + hole] = p[first + parent]
        hole = parent
        parent = (hole - 1) // 2
    k[first + hole] = vk
    p[first + hole] = vp


@njit(cache=True, nogil=True)
def _adjust_heap(k, p, first, hole, length, vk, vp):
    top = hole
    second = hole
    while second < (length - 1) // 2:
        second = 2 * (second + 1)
        if k[first + second] < k[first + second - 1]:
            second -= 1
        k[first + hole] = k[first + second]
        p[first + hole] = p[first + second]
        hole = second
    if (length & 1) == 0 and second == (length - 2) // 2:
        second = 2 * (second + 1)
        k[first + hole] = k[first + second - 1]
        p[first + hole] = p[first + second - 1]
        hole = second - 1
    _push_heap(k, p, first, hole, top, vk, vp)


@njit(cache=True, nogil=True)
def _heap_sort(k, p, first, last):
    """``__partial_sort(first, last, last)``: ``__make_heap`` then ``__sort_heap``."""
    length = last - first
    if length >= 2:
        parent = (length - 2) // 2
        while True:
            _adjust_heap(k, p, first, parent, length, k[first + parent], p[first + parent])
            if parent == 0:
                break
            parent -= 1
    while last - first > 1:
        last -= 1
        vk, vp = k[last], p[last]
        k[last], p[last] = k[first], p[first]
        _adjust_heap(k, p, first, 0, last - first, vk, vp)


@njit(cache=True, nogil=True)
def _introsort_loop(k, p, first, last, depth_limit):
    """``__introsort_loop``: it recurses on the right part and loops on the left one; the parts
    are disjoint, so an explicit stack (numba's cache cannot hold a recursive function) leaves
    the same order."""
    stack = np.empty((128, 3), np.int64)
    stack[0, 0], stack[0, 1], stack[0, 2] = first, last, depth_limit
    top = 1
    while top > 0:
        top -= 1
        first, last, depth_limit = stack[top, 0], stack[top, 1], stack[top, 2]
        while last - first > THRESHOLD:
            if depth_limit == 0:
                _heap_sort(k, p, first, last)
                break
            depth_limit -= 1
            mid = first + (last - first) // 2
            _move_median_to_first(k, p, first, first + 1, mid, last - 1)
            cut = _unguarded_partition(k, p, first + 1, last, first)
            if top == stack.shape[0]:
                grown = np.empty((2 * top, 3), np.int64)
                grown[:top] = stack
                stack = grown
            stack[top, 0], stack[top, 1], stack[top, 2] = cut, last, depth_limit
            top += 1
            last = cut


@njit(cache=True, nogil=True)
def _unguarded_linear_insert(k, p, last):
    vk, vp = k[last], p[last]
    nxt = last - 1
    while vk < k[nxt]:
        k[last] = k[nxt]
        p[last] = p[nxt]
        last = nxt
        nxt -= 1
    k[last] = vk
    p[last] = vp


@njit(cache=True, nogil=True)
def _insertion_sort(k, p, first, last):
    if first == last:
        return
    for i in range(first + 1, last):
        if k[i] < k[first]:
            vk, vp = k[i], p[i]
            for j in range(i, first, -1):
                k[j] = k[j - 1]
                p[j] = p[j - 1]
            k[first] = vk
            p[first] = vp
        else:
            _unguarded_linear_insert(k, p, i)


@njit(cache=True, nogil=True)
def std_sort_order(keys, depth_limit=-1):
    """The permutation ``std::sort`` applies to ``keys`` (1-D, compared with ``<``): element
    ``i`` of the sorted sequence is ``keys[order[i]]``, equal keys in libstdc++'s order.
    ``depth_limit``: the quicksort depth before heapsort takes over (default ``2 * floor(log2
    n)``, ``std::sort``'s; the tests lower it to reach the heapsort)."""
    n = keys.shape[0]
    p = np.arange(n)
    k = keys.copy()
    if n > 1:
        if depth_limit < 0:
            lg = 63
            while not (n >> lg) & 1:
                lg -= 1
            depth_limit = 2 * lg
        _introsort_loop(k, p, 0, n, depth_limit)
        if n > THRESHOLD:
            _insertion_sort(k, p, 0, THRESHOLD)
            for i in range(THRESHOLD, n):
                _unguarded_linear_insert(k, p, i)
        else:
            _insertion_sort(k, p, 0, n)
    return p
