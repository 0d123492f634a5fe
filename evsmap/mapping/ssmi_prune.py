"""SSMI's pruning on evsmap's leaf arrays, compiled: what ``SemanticOcTree::updateNodeRecurs``
does to the tree around one updated voxel (ExistentialRobotics/SSMI, ``SSMI-Mapping``,
``SemanticOcTree.hxx``), kept as leaves expanded to the finest level.

SSMI updates with ``lazy_eval`` false, so after every ``updateNode`` that passes
``checkNeedsUpdate`` the voxel's ancestors are visited bottom-up and each is pruned when
``isNodeCollapsible`` holds: 8 children that exist, have no children, equal value, and equal
semantics unless child 0 is free (``value <= minOccupancyLogOdds``). ``pruneNode`` then
``copyData``s child 0 into the parent and, when child 0's colour is set, gives it the average of
its children's set colours (``getAverageChildColor``, integer division). Later, an update of a
voxel under a pruned node first expands it (``expandNode``: 8 copies of the node) on the way
down.

Leaves stand for the pruned nodes here: when a block of ``8**L`` leaves is pruned every leaf of
it takes the pruned node's data, so the block reads as its 8 copies would after an expansion,
and :data:`level` records, per leaf, the level of the childless node holding it (0: the leaf
itself, ``L``: a node pruned ``L`` levels above the leaves). An expansion then only lowers the
levels of the block's leaves: each leaf's holder becomes its block under the lowest ancestor it
shares with the updated voxel.

The leaves are evsmap's sorted codes (``(x << 32) | (y << 16) | z``); a block's leaves are found
by binary search, one run of ``2**L`` consecutive ``z`` per ``(x, y)`` (a pruned block has every
leaf). A leaf inserted for this frame but not updated yet (``pending``) does not exist in SSMI's
tree yet, so it blocks pruning like a missing child.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from evsmap.mapping.keys import TREE_DEPTH


@njit(cache=True, nogil=True)
def _find(codes, x, y, z):
    """Index of the leaf at key (x, y, z), or -1."""
    c = (np.int64(x) << 32) | (np.int64(y) << 16) | np.int64(z)
    i = np.searchsorted(codes, c)
    if i < codes.shape[0] and codes[i] == c:
        return i
    return -1


@njit(cache=True, nogil=True)
def _same_semantics(cols, lo, others, a, b):
    """``SemanticsLogOdds::operator==``: the 3 slots' colours and log-odds and others."""
    for i in range(3):
        if cols[a, i] != cols[b, i] or lo[a, i] != lo[b, i]:
            return False
    return others[a] == others[b]


@njit(cache=True, nogil=True)
def _children(codes, level, pending, value, x, y, z, depth, v, reps):
    """The representative leaf (first corner) of each of the 8 children of the block of
    ``depth`` levels holding key (x, y, z), in OctoMap's child order, into ``reps``; False when
    a child does not exist as a childless node (a missing or pending leaf, or a block that is
    not pruned at ``depth - 1``) or its value is not ``v`` (the updated leaf's: collapsing
    needs them equal, and most checks end there).

    Children 4..7 lie ``2**(depth - 1)`` places after children 0..3 in the sorted codes when
    both are whole pruned blocks (one run of ``z`` per ``(x, y)``), so only 4 are searched."""
    half = 1 << (depth - 1)
    bx = (x >> depth) << depth
    by = (y >> depth) << depth
    bz = (z >> depth) << depth
    n = codes.shape[0]
    for c in range(8):
        cx, cy = bx + (c & 1) * half, by + ((c >> 1) & 1) * half
        if c < 4:
            r = _find(codes, cx, cy, bz)
        else:
            r = reps[c - 4] + half
            want = (np.int64(cx) << 32) | (np.int64(cy) << 16) | np.int64(bz + half)
            if r >= n or codes[r] != want:
                return False
        if r < 0 or pending[r] or level[r] != depth - 1 or value[r] != v:
            return False
        reps[c] = r
    return True


@njit(cache=True, nogil=True)
def _collapsible(value, cols, lo, others, reps, min_occupancy):
    """``isNodeCollapsible`` over the children's representatives, whose values
    :func:`_children` found equal: equal semantics too, unless child 0 is free."""
    first = reps[0]
    if value[first] <= min_occupancy:
        return True
    for c in range(1, 8):
        if not _same_semantics(cols, lo, others, reps[c], first):
            return False
    return True


@njit(cache=True, nogil=True)
def _pruned_colour(rgb, reps, out):
    """``pruneNode``'s colour: child 0's, replaced by the average of the set colours of the
    children when child 0's is set."""
    first = reps[0]
    for i in range(3):
        out[i] = rgb[first, i]
    if rgb[first, 0] == 255 and rgb[first, 1] == 255 and rgb[first, 2] == 255:
        return
    total = np.zeros(3, np.int64)
    count = 0
    for c in range(8):
        r = reps[c]
        if rgb[r, 0] != 255 or rgb[r, 1] != 255 or rgb[r, 2] != 255:
            for i in range(3):
                total[i] += np.int64(rgb[r, i])
            count += 1
    for i in range(3):
        out[i] = total[i] // count


@njit(cache=True, nogil=True)
def _copy_into_block(codes, x, y, z, depth, src, colour, value, cols, lo, others, rgb, dirty,
                     level):
    """Every leaf of the block of ``depth`` levels holding (x, y, z) becomes a copy of leaf
    ``src`` with ``colour``, held by the pruned node (level ``depth``), and is marked
    ``dirty`` (its semantics may have changed)."""
    side = 1 << depth
    bx = (x >> depth) << depth
    by = (y >> depth) << depth
    bz = (z >> depth) << depth
    v, ot = value[src], others[src]
    c0, c1, c2 = cols[src, 0], cols[src, 1], cols[src, 2]
    l0, l1, l2 = lo[src, 0], lo[src, 1], lo[src, 2]
    for dx in range(side):
        for dy in range(side):
            start = _find(codes, bx + dx, by + dy, bz)
            for n in range(start, start + side):
                value[n], others[n] = v, ot
                cols[n, 0], cols[n, 1], cols[n, 2] = c0, c1, c2
                lo[n, 0], lo[n, 1], lo[n, 2] = l0, l1, l2
                dirty[n] = True
                rgb[n, 0], rgb[n, 1], rgb[n, 2] = colour[0], colour[1], colour[2]
                level[n] = depth


@njit(cache=True, nogil=True)
def expand(codes, level, n):
    """``expandNode`` down to leaf ``n`` of a pruned block: each leaf of the block is then held
    by its block under the lowest ancestor it shares with ``n`` (n itself by nothing)."""
    depth = level[n]
    if depth == 0:
        return
    c = codes[n]
    x, y, z = (c >> 32) & 0xFFFF, (c >> 16) & 0xFFFF, c & 0xFFFF
    side = 1 << depth
    bx = (x >> depth) << depth
    by = (y >> depth) << depth
    bz = (z >> depth) << depth
    for dx in range(side):
        for dy in range(side):
            start = _find(codes, bx + dx, by + dy, bz)
            for dz in range(side):
                diff = ((bx + dx) ^ x) | ((by + dy) ^ y) | ((bz + dz) ^ z)
                held = 0  # the highest bit where the keys differ: the sibling block's level
                while diff > 1:
                    diff >>= 1
                    held += 1
                level[start + dz] = held


@njit(cache=True, nogil=True)
def prune_up(codes, level, pending, n, value, cols, lo, others, rgb, dirty, min_occupancy,
             reps, colour):
    """``pruneNode`` on each ancestor of leaf ``n`` bottom-up, until one is not collapsible.
    Returns the number of levels pruned."""
    c = codes[n]
    x, y, z = (c >> 32) & 0xFFFF, (c >> 16) & 0xFFFF, c & 0xFFFF
    # the z sibling is next to n in the sorted codes: most updates stop at its value
    sib = n + 1 if z & 1 == 0 else n - 1
    if sib < 0 or sib >= codes.shape[0] or codes[sib] != c ^ 1 or pending[sib] \
            or value[sib] != value[n]:
        return 0
    done = 0
    for depth in range(1, TREE_DEPTH + 1):
        if not _children(codes, level, pending, value, x, y, z, depth, value[n], reps):
            break
        if not _collapsible(value, cols, lo, others, reps, min_occupancy):
            break
        _pruned_colour(rgb, reps, colour)
        _copy_into_block(codes, x, y, z, depth, reps[0], colour, value, cols, lo, others, rgb,
                         dirty, level)
        done += 1
    return done

