"""Compiled pieces of semantic_slam's ``octomap_generator`` (floatlazer/semantic_slam, against
OctoMap 1.8 and PCL 1.8), ported from reading its C++ for :mod:`baselines.semantic_slam`.

* :func:`~evsmap.mapping.voxel_grid.voxel_grid` - PCL's ``VoxelGrid<PCLPointCloud2>`` (shared
  with SSMI's generator, so it lives in :mod:`evsmap.mapping.voxel_grid`).
* :func:`fuse_bayes` / :func:`fuse_max` - ``SemanticsBayesian::semanticFusion`` and
  ``SemanticsMax::semanticFusion`` in ``float`` with the ``double`` constants ALPHA 0.8 and
  EPSILON 0.001, and libstdc++'s ``std::sort`` (an insertion sort below 17 elements: stable
  ascending, so the later of two equal confidences ends up first once the top 3 are taken from
  the back).
* A node pool holding the ``SemanticsOcTree`` exactly as OctoMap keeps it: :func:`update_nodes`
  is ``OccupancyOcTreeBase::updateNode`` with ``lazy_eval`` false (early abort on a saturated
  voxel, expansion of a pruned node on the way down, ``pruneNode`` - semantic_slam's, comparing
  log-odds and semantics - or ``updateOccupancyChildren`` on the way up), :func:`fuse_points`
  is ``averageNodeColor`` + ``updateNodeSemantics`` on whatever node ``search`` finds (a pruned
  node takes the observation for its whole block), :func:`export` walks the tree in OctoMap's
  pre-order and computes the inner nodes as ``updateInnerOccupancy`` does (max log-odds, average
  child colour, children's semantics fused pairwise in child order).

Semantics are colours, as in semantic_slam: ``uint32`` ``0x00RRGGBB``, white ``0xFFFFFF`` meaning
"not set".
"""

from __future__ import annotations

import numpy as np
from numba import njit

from evsmap.mapping.generator import WHITE
from evsmap.mapping.voxel_grid import voxel_grid  # noqa: F401 - the generator's filter

ALPHA = 0.8
EPSILON = 0.001
TREE_DEPTH = 16

# node-pool state slots
ROOT, USED, FREE_TOP = 0, 1, 2
HEADROOM = 16 * 8 + 16
"""Nodes one ``updateNode`` can create at most (an expansion of 8 on each of 16 levels)."""


# ----------------------------------------------------------------------------- cloud
@njit(cache=True, nogil=True)
def cloud_fields(pixels, classes, probs, slots, palette, colours_hw3):
    """semantic_cloud.py's per-point fields for the points at flat ``pixels``: float32 (N,
    2 * slots) - the top ``slots`` classes as packed ``palette`` colours (float bits; white
    for a missing class) then their confidences (0 when missing) - and the points' uint8
    colours (N, 3) (zeros when ``colours_hw3`` is empty)."""
    n = pixels.shape[0]
    k = classes.shape[1]
    fields = np.zeros((n, 2 * slots), np.float32)
    bits = fields.view(np.uint32)
    rgb = np.zeros((n, 3), np.uint8)
    has_rgb = colours_hw3.shape[0] > 0
    for i in range(n):
        p = pixels[i]
        for s in range(slots):
            if s < k and classes[p, s] >= 0:
                bits[i, s] = palette[classes[p, s]]
                fields[i, slots + s] = probs[p, s]
            else:
                bits[i, s] = WHITE
        if has_rgb:
            for a in range(3):
                rgb[i, a] = colours_hw3[p, a]
    return fields, rgb


# ----------------------------------------------------------------------------- fusion
@njit(cache=True, nogil=True)
def fuse_bayes(c1, f1, c2, f2, out_c, out_f):
    """``SemanticsBayesian::semanticFusion(s1, s2)`` of 3 (colour, confidence) pairs each;
    writes the result (most confident first) to ``out_c`` / ``out_f``."""
    cols = np.empty(6, np.uint32)
    conf = np.empty(6, np.float32)
    conf2 = np.empty(6, np.float32)
    for i in range(3):
        cols[i] = c1[i]
        conf[i] = f1[i]
    o1 = np.float32(1.0)
    o2 = np.float32(1.0)
    for i in range(3):
        o1 = np.float32(o1 - f1[i])
        o2 = np.float32(o2 - f2[i])
    if np.float64(o1) <= EPSILON:
        o1 = np.float32(EPSILON)
    if np.float64(o2) <= EPSILON:
        o2 = np.float32(EPSILON)
    for i in range(3):
        found = False
        for j in range(3):
            if cols[i] == c2[j]:
                conf2[i] = f2[j]
                found = True
                break
        if not found:
            conf2[i] = np.float32(ALPHA * np.float64(o2))
            o2 = np.float32(np.float64(o2) - ALPHA * np.float64(o2))
    n = 3
    for i in range(3):
        found = False
        for j in range(3):  # only s1's three colours, as the C++ loop bound says
            if c2[i] == cols[j]:
                found = True
                break
        if not found:
            cols[n] = c2[i]
            conf[n] = np.float32(ALPHA * np.float64(o1))
            o1 = np.float32(np.float64(o1) - ALPHA * np.float64(o1))
            conf2[n] = f2[i]
            n += 1
    total = np.float32(o1 * o2)
    for i in range(n):
        conf[i] = np.float32(conf[i] * conf2[i])
        total = np.float32(total + conf[i])
    for i in range(n):
        conf[i] = np.float32(conf[i] / total)
        if np.float64(conf[i]) < EPSILON:
            conf[i] = np.float32(EPSILON)
    # libstdc++ insertion sort, ascending by confidence (stable)
    for i in range(1, n):
        vc = cols[i]
        vf = conf[i]
        j = i
        while j > 0 and vf < conf[j - 1]:
            cols[j] = cols[j - 1]
            conf[j] = conf[j - 1]
            j -= 1
        cols[j] = vc
        conf[j] = vf
    for i in range(3):
        out_c[i] = cols[n - 1 - i]
        out_f[i] = conf[n - 1 - i]


@njit(cache=True, nogil=True)
def fuse_max(c1, f1, c2, f2, out_c, out_f):
    """``SemanticsMax::semanticFusion(s1, s2)`` (one colour and confidence each)."""
    if c1[0] == c2[0]:
        out_c[0] = c1[0]
        out_f[0] = np.float32(np.float64(np.float32(f1[0] + f2[0])) / 2.0)
    else:
        if f1[0] > f2[0]:
            out_c[0] = c1[0]
            v = f1[0]
        else:
            out_c[0] = c2[0]
            v = f2[0]
        out_f[0] = np.float32(np.float64(v) * 0.9)


@njit(cache=True, nogil=True)
def _fuse(bayes, c1, f1, c2, f2, out_c, out_f):
    if bayes:
        fuse_bayes(c1, f1, c2, f2, out_c, out_f)
    else:
        fuse_max(c1, f1, c2, f2, out_c, out_f)


# ----------------------------------------------------------------------------- node pool
@njit(cache=True, nogil=True)
def _child_pos(k0, k1, k2, bit):
    pos = 0
    if k0 & (1 << bit):
        pos += 1
    if k1 & (1 << bit):
        pos += 2
    if k2 & (1 << bit):
        pos += 4
    return pos


@njit(cache=True, nogil=True)
def _has_children(children, n):
    for i in range(8):
        if children[n, i] >= 0:
            return True
    return False


@njit(cache=True, nogil=True)
def _new_node(st, children, value, rgb, scol, sconf, free, default_conf):
    if st[FREE_TOP] > 0:
        st[FREE_TOP] -= 1
        n = free[st[FREE_TOP]]
    else:
        n = st[USED]
        st[USED] += 1
    for i in range(8):
        children[n, i] = -1
    value[n] = 0.0
    for i in range(3):
        rgb[n, i] = 255
    for s in range(scol.shape[1]):
        scol[n, s] = WHITE
        sconf[n, s] = default_conf
    return n


@njit(cache=True, nogil=True)
def _copy_data(dst, src, value, rgb, scol, sconf):
    value[dst] = value[src]
    for i in range(3):
        rgb[dst, i] = rgb[src, i]
    for s in range(scol.shape[1]):
        scol[dst, s] = scol[src, s]
        sconf[dst, s] = sconf[src, s]


@njit(cache=True, nogil=True)
def search(children, root, k0, k1, k2):
    """``OcTreeBaseImpl::search``: the finest node holding the key, a pruned node covering it,
    or -1."""
    if root < 0:
        return -1
    n = root
    for d in range(TREE_DEPTH):
        c = children[n, _child_pos(k0, k1, k2, TREE_DEPTH - 1 - d)]
        if c < 0:
            if not _has_children(children, n):
                return n
            return -1
        n = c
    return n


@njit(cache=True, nogil=True)
def _colour_set(rgb, n):
    return rgb[n, 0] != 255 or rgb[n, 1] != 255 or rgb[n, 2] != 255


@njit(cache=True, nogil=True)
def _average_child_colour(children, rgb, n, out):
    mr = 0
    mg = 0
    mb = 0
    c = 0
    for i in range(8):
        ch = children[n, i]
        if ch >= 0 and _colour_set(rgb, ch):
            mr += np.int64(rgb[ch, 0])
            mg += np.int64(rgb[ch, 1])
            mb += np.int64(rgb[ch, 2])
            c += 1
    if c > 0:
        out[0] = mr // c
        out[1] = mg // c
        out[2] = mb // c
    else:
        out[0] = 255
        out[1] = 255
        out[2] = 255


@njit(cache=True, nogil=True)
def _try_prune(st, children, value, rgb, scol, sconf, free, n, tmp):
    """semantic_slam's ``pruneNode``: collapse ``n`` when its 8 children exist, are leaves and
    have equal log-odds and semantics (colour ignored); True when pruned."""
    first = children[n, 0]
    if first < 0 or _has_children(children, first):
        return False
    for i in range(1, 8):
        c = children[n, i]
        if c < 0 or _has_children(children, c) or value[c] != value[first]:
            return False
        for s in range(scol.shape[1]):
            if scol[c, s] != scol[first, s] or sconf[c, s] != sconf[first, s]:
                return False
    _copy_data(n, first, value, rgb, scol, sconf)
    if _colour_set(rgb, n):
        _average_child_colour(children, rgb, n, tmp)
        for i in range(3):
            rgb[n, i] = tmp[i]
    for i in range(8):
        free[st[FREE_TOP]] = children[n, i]
        st[FREE_TOP] += 1
        children[n, i] = -1
    return True


@njit(cache=True, nogil=True)
def update_nodes(keys, hits, start, st, children, value, rgb, scol, sconf, free, hit_lo, miss_lo,
                 clamp_min, clamp_max, default_conf):
    """``updateNode(key, hits[u], lazy_eval=false)`` for ``u = start, start + 1, ...``; stops
    early (returning the next ``u``) when the pool could run out of nodes, else returns
    ``len(keys)``."""
    path = np.empty(TREE_DEPTH, np.int64)
    tmp = np.empty(3, np.int64)
    cap = children.shape[0]
    for u in range(start, keys.shape[0]):
        if st[USED] + HEADROOM > cap and st[FREE_TOP] < HEADROOM:
            return u
        k0, k1, k2 = keys[u, 0], keys[u, 1], keys[u, 2]
        upd = hit_lo if hits[u] else miss_lo
        leaf = search(children, st[ROOT], k0, k1, k2)
        if leaf >= 0 and ((upd >= 0 and value[leaf] >= clamp_max)
                          or (upd <= 0 and value[leaf] <= clamp_min)):
            continue  # early abort: no change will happen
        created = False
        if st[ROOT] < 0:
            st[ROOT] = _new_node(st, children, value, rgb, scol, sconf, free, default_conf)
            created = True
        n = st[ROOT]
        for d in range(TREE_DEPTH):
            pos = _child_pos(k0, k1, k2, TREE_DEPTH - 1 - d)
            if children[n, pos] < 0:
                if not _has_children(children, n) and not created:
                    for i in range(8):  # expandNode: 8 copies of the pruned node
                        c = _new_node(st, children, value, rgb, scol, sconf, free, default_conf)
                        _copy_data(c, n, value, rgb, scol, sconf)
                        children[n, i] = c
                    created = False
                else:
                    children[n, pos] = _new_node(st, children, value, rgb, scol, sconf, free,
                                                 default_conf)
                    created = True
            else:
                created = False
            path[d] = n
            n = children[n, pos]
        v = np.float32(value[n] + upd)
        if v < clamp_min:
            v = clamp_min
        elif v > clamp_max:
            v = clamp_max
        value[n] = v
        for d in range(TREE_DEPTH - 1, -1, -1):
            p = path[d]
            if not _try_prune(st, children, value, rgb, scol, sconf, free, p, tmp):
                best = np.float32(-3.4028234663852886e38)
                for i in range(8):
                    c = children[p, i]
                    if c >= 0 and value[c] > best:
                        best = value[c]
                value[p] = best
    return keys.shape[0]


@njit(cache=True, nogil=True)
def fuse_points(keys, ok, point_rgb, colours, confs, use_rgb, st, children, value, rgb, scol,
                sconf, bayes):
    """For each point in order: ``averageNodeColor`` (when ``use_rgb``) and
    ``updateNodeSemantics`` on the node ``search`` finds (nothing when none). Returns the number
    of fusions done."""
    s_count = scol.shape[1]
    obs_c = np.empty(s_count, np.uint32)
    obs_f = np.empty(s_count, np.float32)
    out_c = np.empty(s_count, np.uint32)
    out_f = np.empty(s_count, np.float32)
    done = 0
    for m in range(keys.shape[0]):
        if not ok[m]:
            continue
        n = search(children, st[ROOT], keys[m, 0], keys[m, 1], keys[m, 2])
        if n < 0:
            continue
        if use_rgb:
            if _colour_set(rgb, n):
                for i in range(3):
                    rgb[n, i] = np.uint8((np.int64(rgb[n, i]) + np.int64(point_rgb[m, i])) // 2)
            else:
                for i in range(3):
                    rgb[n, i] = point_rgb[m, i]
        is_set = False
        for s in range(s_count):
            obs_c[s] = colours[m, s]
            obs_f[s] = confs[m, s]
            if scol[n, s] != WHITE:
                is_set = True
        if is_set:
            _fuse(bayes, scol[n], sconf[n], obs_c, obs_f, out_c, out_f)
            for s in range(s_count):
                scol[n, s] = out_c[s]
                sconf[n, s] = out_f[s]
        else:
            for s in range(s_count):
                scol[n, s] = obs_c[s]
                sconf[n, s] = obs_f[s]
        done += 1
    return done


@njit(cache=True, nogil=True)
def export(st, children, value, rgb, scol, sconf, bayes, default_conf):
    """The tree in OctoMap's pre-order: ``(depth uint8, keys (M, 3) int64, child_mask uint8,
    value float32, rgb (M, 3) uint8, colours (M, S) uint32, confs (M, S) float32)``, inner nodes
    as ``updateInnerOccupancy`` leaves them."""
    s_count = scol.shape[1]
    total = st[USED] - st[FREE_TOP]
    depth = np.zeros(total, np.uint8)
    keys = np.zeros((total, 3), np.int64)
    mask = np.zeros(total, np.uint8)
    node = np.empty(total, np.int64)
    out_v = np.empty(total, np.float32)
    out_rgb = np.empty((total, 3), np.uint8)
    out_c = np.empty((total, s_count), np.uint32)
    out_f = np.empty((total, s_count), np.float32)
    if st[ROOT] < 0:
        return (depth[:0], keys[:0], mask[:0], out_v[:0], out_rgb[:0], out_c[:0], out_f[:0])
    # pre-order walk with an explicit stack (children pushed 7..0 so 0 comes out first)
    stack_n = np.empty(TREE_DEPTH * 8 + 8, np.int64)
    stack_d = np.empty(TREE_DEPTH * 8 + 8, np.int64)
    stack_k = np.empty((TREE_DEPTH * 8 + 8, 3), np.int64)
    top = 0
    stack_n[0] = st[ROOT]
    stack_d[0] = 0
    stack_k[0, :] = 0
    top = 1
    m = 0
    while top > 0:
        top -= 1
        n = stack_n[top]
        d = stack_d[top]
        node[m] = n
        depth[m] = d
        for a in range(3):
            keys[m, a] = stack_k[top, a]
        bits = 0
        for i in range(8):
            if children[n, i] >= 0:
                bits |= 1 << i
        mask[m] = bits
        k0, k1, k2 = keys[m, 0], keys[m, 1], keys[m, 2]
        m += 1
        for i in range(7, -1, -1):
            c = children[n, i]
            if c >= 0:
                stack_n[top] = c
                stack_d[top] = d + 1
                b = TREE_DEPTH - 1 - d
                stack_k[top, 0] = k0 | ((i & 1) << b)
                stack_k[top, 1] = k1 | (((i >> 1) & 1) << b)
                stack_k[top, 2] = k2 | (((i >> 2) & 1) << b)
                top += 1
    # row of each pool node, then the inner nodes bottom-up (reverse pre-order)
    row = np.full(children.shape[0], -1, np.int64)
    for i in range(m):
        row[node[i]] = i
        n = node[i]
        out_v[i] = value[n]
        for a in range(3):
            out_rgb[i, a] = rgb[n, a]
        for s in range(s_count):
            out_c[i, s] = scol[n, s]
            out_f[i, s] = sconf[n, s]
    tmp_c = np.empty(s_count, np.uint32)
    tmp_f = np.empty(s_count, np.float32)
    for i in range(m - 1, -1, -1):
        if mask[i] == 0:
            continue
        n = node[i]
        best = np.float32(-3.4028234663852886e38)
        mr = 0
        mg = 0
        mb = 0
        cnt = 0
        started = False
        for s in range(s_count):
            tmp_c[s] = WHITE
            tmp_f[s] = default_conf
        for j in range(8):
            c = children[n, j]
            if c < 0:
                continue
            r = row[c]
            if out_v[r] > best:
                best = out_v[r]
            if out_rgb[r, 0] != 255 or out_rgb[r, 1] != 255 or out_rgb[r, 2] != 255:
                mr += np.int64(out_rgb[r, 0])
                mg += np.int64(out_rgb[r, 1])
                mb += np.int64(out_rgb[r, 2])
                cnt += 1
            child_set = False
            for s in range(s_count):
                if out_c[r, s] != WHITE:
                    child_set = True
            if child_set:
                if started:
                    _fuse(bayes, tmp_c.copy(), tmp_f.copy(), out_c[r], out_f[r], tmp_c, tmp_f)
                else:
                    for s in range(s_count):
                        tmp_c[s] = out_c[r, s]
                        tmp_f[s] = out_f[r, s]
                    started = True
        out_v[i] = best
        if cnt > 0:
            out_rgb[i, 0] = mr // cnt
            out_rgb[i, 1] = mg // cnt
            out_rgb[i, 2] = mb // cnt
        else:
            out_rgb[i, 0] = 255
            out_rgb[i, 1] = 255
            out_rgb[i, 2] = 255
        for s in range(s_count):
            out_c[i, s] = tmp_c[s]
            out_f[i, s] = tmp_f[s]
    return depth[:m], keys[:m], mask[:m], out_v[:m], out_rgb[:m], out_c[:m], out_f[:m]
