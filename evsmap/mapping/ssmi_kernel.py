"""SSMI's node update (ExistentialRobotics/SSMI, ``SSMI-Mapping``) on evsmap's leaf arrays,
compiled: what ``OctomapGenerator::insertPointCloud`` does to the leaves of a
``SemanticOcTree<SemanticsLogOdds>`` in one frame.

A node is SSMI's: occupancy log-odds ``value``, colour ``rgb`` (255, 255, 255 = unset), and
``SemanticsLogOdds``: 3 (class colour ``0x00RRGGBB``, log-odds) slots, most likely first, unset
slots white at ``LOGINIT`` -0.1, and ``others`` (-0.1 when unset). All arithmetic in ``float``
with SSMI's ``float`` constants, in the C++'s order:

* :func:`hit` - ``updateNode(x, y, z, true, class_obs, color_obs, false)`` for one centroid:
  ``checkNeedsUpdate`` (nothing changes when the node is saturated on this class),
  ``averageNodeColor``, then ``SemanticsLogOdds::fuseObs`` (a node with semantics) or
  ``initSemantics`` (one without: the class at ``log 0.1 + value + psi``, others at
  ``log 0.9 + value + phi``), and ``value = getOccFromSem``.
* :func:`free` - ``updateNode(key, false)`` for one key of ``insertPointCloud``'s free set:
  nothing when ``value <= minOccupancyLogOdds`` (``log 4 + min``), else ``averageNodeColor``
  with white (the default ``color_obs``) and ``fuseObsFree`` (or ``value + phi`` floored at
  ``minOccupancyLogOdds`` for a node without semantics).

``fuseObs``'s details kept: the stored classes get ``+psi`` (capped) or ``+phi`` (floored); a
class not stored enters at ``others + log 0.8 + psi`` *uncapped* and ``others += log 0.2 +
phi``; ``std::sort`` of at most 4 entries is libstdc++'s insertion sort (stable, ascending); a
4th entry folds into others as ``log(exp(others) + exp(l))``; others is clamped last.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from evsmap.mapping.generator import WHITE
from evsmap.mapping.mcb_nodes import LOGINIT
from evsmap.mapping.ssmi_prune import expand, prune_up

LOG_ALPHA = np.float32(math.log(0.8))
LOG_MINUS_ALPHA = np.float32(math.log(0.2))
LOG_BETA = np.float32(math.log(0.1))
LOG_MINUS_BETA = np.float32(math.log(0.9))


def tree_constants(*, psi: float, phi: float, clamp_min: float, clamp_max: float
                   ) -> tuple[np.float32, np.float32, np.float32, np.float32, np.float32]:
    """``(psi, phi, minLogOdds, maxLogOdds, minOccupancyLogOdds)`` as the tree holds them:
    ``setPsi(float)``, ``setPhi(float)``, ``setMinLogOdds(float p)`` = ``logodds(p)`` as float
    and ``minOccupancyLogOdds = log(4.) + minLogOdds`` as float."""
    def logodds(p: float) -> np.float32:
        p = float(np.float32(p))
        return np.float32(math.log(p / (1.0 - p)))

    lo = logodds(clamp_min)
    return (np.float32(psi), np.float32(phi), lo, logodds(clamp_max),
            np.float32(math.log(4.0) + float(lo)))


@njit(cache=True, nogil=True)
def occupancy(cols, lo, others, n):
    """``getOccFromSem``: ``log(exp(others) + sum of exp(l) over the set slots)`` in float."""
    occ = np.float32(np.exp(others[n]))
    for i in range(3):
        if cols[n, i] != WHITE:
            occ = np.float32(occ + np.float32(np.exp(lo[n, i])))
    return np.float32(np.log(occ))


@njit(cache=True, nogil=True)
def occupancies(cols, lo, others):
    """:func:`occupancy` of every row (glibc's ``expf`` / ``logf``, as the C++ calls them;
    numpy's vectorised float32 ``exp`` can differ in the last bit)."""
    out = np.empty(cols.shape[0], np.float32)
    for n in range(cols.shape[0]):
        out[n] = occupancy(cols, lo, others, n)
    return out


@njit(cache=True, nogil=True)
def _average_colour(rgb, n, r, g, b):
    if rgb[n, 0] != 255 or rgb[n, 1] != 255 or rgb[n, 2] != 255:
        rgb[n, 0] = np.uint8((np.int64(rgb[n, 0]) + r) // 2)
        rgb[n, 1] = np.uint8((np.int64(rgb[n, 1]) + g) // 2)
        rgb[n, 2] = np.uint8((np.int64(rgb[n, 2]) + b) // 2)
    else:
        rgb[n, 0], rgb[n, 1], rgb[n, 2] = r, g, b


@njit(cache=True, nogil=True)
def _semantics_set(cols, n):
    return cols[n, 0] != WHITE or cols[n, 1] != WHITE or cols[n, 2] != WHITE


@njit(cache=True, nogil=True)
def _fuse_obs(cols, lo, others, n, obs, psi, phi, lmin, lmax):
    vc = np.empty(4, np.uint32)
    vl = np.empty(4, np.float32)
    m = 0
    ot = others[n]
    is_others = True
    for i in range(3):
        if cols[n, i] != WHITE:
            vc[m] = cols[n, i]
            v = lo[n, i]
            if obs == cols[n, i]:
                is_others = False
                v = np.float32(v + psi)
                if v > lmax:
                    v = lmax
            else:
                v = np.float32(v + phi)
                if v < lmin:
                    v = lmin
            vl[m] = v
            m += 1
    if is_others:
        vc[m] = obs
        vl[m] = np.float32(np.float32(others[n] + LOG_ALPHA) + psi)
        m += 1
        ot = np.float32(ot + np.float32(LOG_MINUS_ALPHA + phi))
    else:
        ot = np.float32(ot + phi)
    for i in range(1, m):  # std::sort of <= 16 elements: insertion sort, ascending, stable
        c, v = vc[i], vl[i]
        j = i
        while j > 0 and v < vl[j - 1]:
            vc[j], vl[j] = vc[j - 1], vl[j - 1]
            j -= 1
        vc[j], vl[j] = c, v
    first = 0
    if is_others and m > 3:
        ot = np.float32(np.log(np.float32(np.float32(np.exp(ot)) + np.float32(np.exp(vl[0])))))
        first = 1
    if ot < lmin:
        ot = lmin
    elif ot > lmax:
        ot = lmax
    others[n] = ot
    kept = m - first
    for i in range(3):
        if i < kept:
            cols[n, i] = vc[m - 1 - i]
            lo[n, i] = vl[m - 1 - i]
        else:
            cols[n, i] = WHITE
            lo[n, i] = LOGINIT


@njit(cache=True, nogil=True)
def _init_semantics(cols, lo, others, value, n, obs, psi, phi, lmin, lmax):
    v = np.float32(np.float32(LOG_BETA + value[n]) + psi)
    if v < lmin:
        v = lmin
    elif v > lmax:
        v = lmax
    o = np.float32(np.float32(LOG_MINUS_BETA + value[n]) + phi)
    if o < lmin:
        o = lmin
    cols[n, 0], lo[n, 0] = obs, v
    for i in range(1, 3):
        cols[n, i], lo[n, i] = WHITE, LOGINIT
    others[n] = o


@njit(cache=True, nogil=True)
def hit(cols, lo, others, value, rgb, n, obs, r, g, b, psi, phi, lmin, lmax):
    """``updateNode(key, true, class_obs=obs, color_obs=(r, g, b))`` on leaf ``n``; returns
    whether the node changed."""
    if (cols[n, 0] == obs and lo[n, 0] >= lmax and lo[n, 1] <= lmin and lo[n, 2] <= lmin
            and others[n] <= lmin):
        return False
    _average_colour(rgb, n, r, g, b)
    if _semantics_set(cols, n):
        _fuse_obs(cols, lo, others, n, obs, psi, phi, lmin, lmax)
    else:
        _init_semantics(cols, lo, others, value, n, obs, psi, phi, lmin, lmax)
    value[n] = occupancy(cols, lo, others, n)
    return True


@njit(cache=True, nogil=True)
def free(cols, lo, others, value, rgb, n, phi, lmin, min_occupancy):
    """``updateNode(key, false)`` on leaf ``n``; returns whether the node changed."""
    if value[n] <= min_occupancy:
        return False
    _average_colour(rgb, n, 255, 255, 255)
    if _semantics_set(cols, n):
        for i in range(3):
            if cols[n, i] != WHITE:
                v = np.float32(lo[n, i] + phi)
                lo[n, i] = lmin if v < lmin else v
        o = np.float32(others[n] + phi)
        others[n] = lmin if o < lmin else o
        value[n] = occupancy(cols, lo, others, n)
    else:
        v = np.float32(value[n] + phi)
        value[n] = min_occupancy if v < min_occupancy else v
    return True


@njit(cache=True, nogil=True)
def frame_update(cols, lo, others, value, rgb, hit_index, hit_colour, hit_rgb, free_index,
                 psi, phi, lmin, lmax, min_occupancy, codes, level, pending, dirty, copies):
    """One frame as SSMI's generator applies it: every centroid's hit in order, then every key
    of the free set. With ``copies`` (SSMI's tree), each update that passes
    ``checkNeedsUpdate`` first expands a pruned block holding the leaf and then prunes its
    ancestors where they collapse (:mod:`evsmap.mapping.ssmi_prune`: ``codes`` the sorted leaf
    codes, ``level`` the pruned level holding each leaf, ``pending`` the leaves this frame
    inserted that SSMI has not created yet). ``dirty`` marks the leaves whose semantics a hit
    or a pruned node's copy changed. Returns the number of leaves changed by hits and by
    misses."""
    reps = np.empty(8, np.int64)
    colour = np.empty(3, np.int64)
    changed_hits = 0
    for t in range(hit_index.shape[0]):
        n = hit_index[t]
        pending[n] = False
        if hit(cols, lo, others, value, rgb, n, hit_colour[t], hit_rgb[t, 0], hit_rgb[t, 1],
               hit_rgb[t, 2], psi, phi, lmin, lmax):
            changed_hits += 1
            dirty[n] = True
            if copies:
                expand(codes, level, n)
                prune_up(codes, level, pending, n, value, cols, lo, others, rgb, dirty,
                         min_occupancy, reps, colour)
    changed_free = 0
    for t in range(free_index.shape[0]):
        n = free_index[t]
        pending[n] = False
        if free(cols, lo, others, value, rgb, n, phi, lmin, min_occupancy):
            changed_free += 1
            if copies:
                expand(codes, level, n)
                prune_up(codes, level, pending, n, value, cols, lo, others, rgb, dirty,
                         min_occupancy, reps, colour)
    return changed_hits, changed_free
