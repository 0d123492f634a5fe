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


@njit(cache=True, nogil=True)
def _swap(p, a, b):
    t = p[a]
    p[a] = p[b]
    p[b] = t


@njit(cache=True, nogil=True)
def _move_median_to_first(keys, p, result, a, b, c):
    if keys[p[a]] < keys[p[b]]:
        if keys[p[b]] < keys[p[c]]:
            _swap(p, result, b)
        elif keys[p[a]] < keys[p[c]]:
            _swap(p, result, c)
        else:
            _swap(p, result, a)
    elif keys[p[a]] < keys[p[c]]:
        _swap(p, result, a)
    elif keys[p[b]] < keys[p[c]]:
        _swap(p, result, c)
    else:
        _swap(p, result, b)


@njit(cache=True, nogil=True)
def _unguarded_partition(keys, p, first, last, pivot):
    while True:
        while keys[p[first]] < keys[p[pivot]]:
            first += 1
        last -= 1
        while keys[p[pivot]] < keys[p[last]]:
            last -= 1
        if not first < last:
            return first
        _swap(p, first, last)
        first += 1


@njit(cache=True, nogil=True)
def _push_heap(keys, p, first, hole, top, value):
    parent = (hole - 1) // 2
    while hole > top and keys[p[first + parent]] < keys[value]:
        p[first + hole] = p[first + parent]
        hole = parent
        parent = (hole - 1) // 2
    p[first + hole] = value


@njit(cache=True, nogil=True)
def _adjust_heap(keys, p, first, hole, length, value):
    top = hole
    second = hole
    while second < (length - 1) // 2:
        second = 2 * (second + 1)
        if keys[p[first + second]] < keys[p[first + second - 1]]:
            second -= 1
        p[first + hole] = p[first + second]
        hole = second
    if (length & 1) == 0 and second == (length - 2) // 2:
        second = 2 * (second + 1)
        p[first + hole] = p[first + second - 1]
        hole = second - 1
    _push_heap(keys, p, first, hole, top, value)


@njit(cache=True, nogil=True)
def _heap_sort(keys, p, first, last):
    """``__partial_sort(first, last, last)``: ``__make_heap`` then ``__sort_heap``."""
    length = last - first
    if length >= 2:
        parent = (length - 2) // 2
        while True:
            _adjust_heap(keys, p, first, parent, length, p[first + parent])
            if parent == 0:
                break
            parent -= 1
    while last - first > 1:
        last -= 1
        value = p[last]
        p[last] = p[first]
        _adjust_heap(keys, p, first, 0, last - first, value)


@njit(cache=True, nogil=True)
def _introsort_loop(keys, p, first, last, depth_limit):
    """``__introsort_loop``: it recurses on the right part and loops on the left one; the parts
    are disjoint, so an explicit stack (numba's cache cannot hold a recursive function) leaves
    the same order."""
    stack = np.empty((128, 3), np.int64)
    top = 0
    stack[0, 0], stack[0, 1], stack[0, 2] = first, last, depth_limit
    top = 1
    while top > 0:
        top -= 1
        first, last, depth_limit = stack[top, 0], stack[top, 1], stack[top, 2]
        while last - first > THRESHOLD:
            if depth_limit == 0:
                _heap_sort(keys, p, first, last)
                break
            depth_limit -= 1
            mid = first + (last - first) // 2
            _move_median_to_first(keys, p, first, first + 1, mid, last - 1)
            cut = _unguarded_partition(keys, p, first + 1, last, first)
            if top == stack.shape[0]:
                grown = np.empty((2 * top, 3), np.int64)
                grown[:top] = stack
                stack = grown
            stack[top, 0], stack[top, 1], stack[top, 2] = cut, last, depth_limit
            top += 1
            last = cut


@njit(cache=True, nogil=True)
def _unguarded_linear_insert(keys, p, last):
    value = p[last]
    nxt = last - 1
    while keys[value] < keys[p[nxt]]:
        p[last] = p[nxt]
        last = nxt
        nxt -= 1
    p[last] = value


@njit(cache=True, nogil=True)
def _insertion_sort(keys, p, first, last):
    if first == last:
        return
    for i in range(first + 1, last):
        if keys[p[i]] < keys[p[first]]:
            value = p[i]
            for j in range(i, first, -1):
                p[j] = p[j - 1]
            p[first] = value
        else:
            _unguarded_linear_insert(keys, p, i)


@njit(cache=True, nogil=True)
def std_sort_order(keys, depth_limit=-1):
    """The permutation ``std::sort`` applies to ``keys`` (1-D, compared with ``<``): element
    ``i`` of the sorted sequence is ``keys[order[i]]``, equal keys in libstdc++'s order.
    ``depth_limit``: the quicksort depth before heapsort takes over (default ``2 * floor(log2
    n)``, ``std::sort``'s; the tests lower it to reach the heapsort)."""
    n = keys.shape[0]
    p = np.arange(n)
    if n > 1:
        if depth_limit < 0:
            lg = 63
            while not (n >> lg) & 1:
                lg -= 1
            depth_limit = 2 * lg
        _introsort_loop(keys, p, 0, n, depth_limit)
        if n > THRESHOLD:
            _insertion_sort(keys, p, 0, THRESHOLD)
            for i in range(THRESHOLD, n):
                _unguarded_linear_insert(keys, p, i)
        else:
            _insertion_sort(keys, p, 0, n)
    return p
