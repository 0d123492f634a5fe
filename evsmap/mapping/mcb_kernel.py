"""Compiled (numba) frame update of the ``multiclass-bayes`` payloads.

One pass per voxel instead of numpy's whole-array passes, doing exactly what the numpy path in
:mod:`evsmap.updaters.multiclass_bayes` does with :func:`evsmap.mapping.fusion.mcb.mcb_miss`,
:func:`~evsmap.mapping.fusion.build_local`, :func:`~evsmap.mapping.fusion.mcb_observe` (the
default eq. 7 leaf update) or :func:`~evsmap.mapping.fusion.merge_algorithm1` (the ``average``
variant) and :func:`~evsmap.mapping.fusion.mcb_occupancy`, operation for operation in the same
float32/float64 types and order (sums in the same order, stable top-3 selection, numpy's
``logaddexp``), so both store the same float32 values; the tests compare them frame by frame.
Only the dense local-map case is compiled (voxels x classes up to ``fusion.DENSE_LIMIT``);
the caller falls back to numpy beyond it.
"""

from __future__ import annotations

import math
from types import ModuleType

import numpy as np

from evsmap.mapping.kernels import blocks

numba: ModuleType | None
try:
    import numba
except ImportError:  # pragma: no cover
    numba = None
prange = numba.prange if numba is not None else range

_VOXEL_BLOCK = 128
"""Local voxels per parallel block (each block allocates its scratch buffers once)."""
_SORT_CHUNKS = 8
_SORT_CHUNK_MIN = 1 << 14
_SORT_CELLS = 1 << 22
"""The counting sort of a frame's points by voxel: at most 8 chunks of at least 16384 points,
and at most 4M per-chunk counters (chunks x voxels)."""

_LOGE2 = math.log(2.0)


def _logaddexp(x, y):
    # numpy's npy_logaddexp
    if x == y:
        return x + _LOGE2
    tmp = x - y
    if tmp > 0:
        return x + math.log1p(math.exp(-tmp))
    if tmp <= 0:
        return y + math.log1p(math.exp(tmp))
    return tmp


def _clip(x, lo, hi):
    if x < lo:
        return lo
    if x > hi:
        return hi
    return x


def _rank(keys, n, out):
    """The stable ascending ranking of the ``n`` keys (``-value``; invalid = +inf) written to
    ``out``: the first 3 are the kept candidates."""
    for i in range(n):
        out[i] = i
    # insertion sort: stable
    for i in range(1, n):
        j = i
        while j > 0 and keys[out[j - 1]] > keys[out[j]]:
            out[j - 1], out[j] = out[j], out[j - 1]
            j -= 1


_LOG_ALPHA = math.log(0.8)
_LOG_ALPHA_REST = math.log(1.0 - 0.8)
_LOG_BETA = math.log(0.1)
_LOG_BETA_REST = math.log(1.0 - 0.1)


def _occupancy(classes, lodds, others, i):
    """``mcb_occupancy`` of leaf ``i`` (same order of operations)."""
    ot = np.float64(others[i])
    top = ot
    for s in range(3):
        if classes[i, s] >= 0 and np.float64(lodds[i, s]) > top:
            top = np.float64(lodds[i, s])
    acc = 0.0
    for s in range(3):
        if classes[i, s] >= 0:
            acc = acc + math.exp(np.float64(lodds[i, s]) - top)
        else:
            acc = acc + 0.0
    acc = acc + math.exp(ot - top)
    return np.float32(math.log(acc) + top)


def _store_ranked(classes, lodds, others, g, cand_cls, cand_lo, cand_ok, rank, new_ot):
    """Leaf ``g`` takes the 3 best-ranked valid candidates (empty slots -1, 0) and
    ``new_ot``."""
    for s in range(3):
        i = rank[s]
        if cand_ok[i]:
            classes[g, s] = cand_cls[i]
            lodds[g, s] = np.float32(cand_lo[i])
        else:
            classes[g, s] = -1
            lodds[g, s] = np.float32(0.0)
    others[g] = np.float32(new_ot)


def _observe(classes, lodds, others, g, y, psi, phi, min_lo, max_lo, cand_cls, cand_lo,
             cand_ok, keys4, rank4):
    """``mcb_observe`` of leaf ``g`` with class ``y`` (-1: no class)."""
    ot = np.float64(others[g])
    if classes[g, 0] < 0:  # no classes yet: initSemantics (or a blind hit on others)
        if y >= 0:
            first = _clip((_LOG_BETA + ot) + psi, min_lo, max_lo)
            rest = (_LOG_BETA_REST + ot) + phi
            if rest < min_lo:
                rest = min_lo
            classes[g, 0] = y
            classes[g, 1] = -1
            classes[g, 2] = -1
            lodds[g, 0] = np.float32(first)
            lodds[g, 1] = np.float32(0.0)
            lodds[g, 2] = np.float32(0.0)
            others[g] = np.float32(rest)
        else:
            v = ot + psi
            others[g] = np.float32(v if v < max_lo else max_lo)
        return
    if y < 0:
        for s in range(3):
            if classes[g, s] >= 0:
                v = np.float64(lodds[g, s]) + phi
                lodds[g, s] = np.float32(v if v > min_lo else min_lo)
        v = ot + psi
        others[g] = np.float32(v if v < max_lo else max_lo)
        return
    found = False
    for s in range(3):
        c = classes[g, s]
        cand_cls[s] = c
        cand_ok[s] = c >= 0
        if c >= 0:
            lo = np.float64(lodds[g, s])
            if c == y:
                found = True
                v = lo + psi
                cand_lo[s] = v if v < max_lo else max_lo
            else:
                v = lo + phi
                cand_lo[s] = v if v > min_lo else min_lo
        else:
            cand_lo[s] = 0.0
    entering = (ot + _LOG_ALPHA) + psi
    cand_cls[3] = y
    cand_lo[3] = entering if entering < max_lo else max_lo
    cand_ok[3] = not found
    if found:
        new_ot = ot + phi
    else:
        new_ot = (ot + _LOG_ALPHA_REST) + phi
    for i in range(4):
        keys4[i] = -cand_lo[i] if cand_ok[i] else np.inf
    _rank(keys4, 4, rank4)
    fourth = rank4[3]
    if cand_ok[fourth]:
        new_ot = _logaddexp(new_ot, cand_lo[fourth])
    _store_ranked(classes, lodds, others, g, cand_cls, cand_lo, cand_ok, rank4,
                  _clip(new_ot, min_lo, max_lo))


def _frame_update(classes, lodds, others, occupancy, free, voxels, local_index, pixels, obs_cls,
                  obs_p, span, psi, phi, theta, min_lo, max_lo, prob_min, empty_floor, bayes,
                  printed, semantic):
    """``obs_cls`` / ``obs_p``: the observation's (H*W, k) classes and probabilities; point ``p``
    is pixel ``pixels[p]`` and lies in local voxel ``local_index[p]`` (map leaf
    ``voxels[local_index[p]]``). ``bayes``: eq. 7 leaf update (else the average variant);
    ``printed``: Algorithm 1's printed pairing (else SSMI's); ``semantic``: write each touched
    leaf's occupancy log-odds from its class vector. Free leaves and local voxels are updated
    in parallel: each writes its own leaf."""
    # ---- rays: fuseObsFree on traversed voxels (mcb_miss), and with semantic occupancy the
    # leaf's occupancy (mcb_occupancy; free and hit voxels are disjoint, and a leaf's occupancy
    # depends on its own state only)
    for i in prange(free.shape[0]):
        f = free[i]
        if classes[f, 0] < 0:
            if not semantic:
                continue
            v = np.float64(others[f]) + phi
            others[f] = np.float32(v if v > empty_floor else empty_floor)
            # no classes: log(exp(others - others)) + others is others itself
            occupancy[f] = others[f]
            continue
        for s in range(3):
            if classes[f, s] >= 0:
                v = np.float64(lodds[f, s]) + phi
                if v < min_lo:
                    v = min_lo
                lodds[f, s] = np.float32(v)
            else:
                lodds[f, s] = np.float32(0.0)
        v = np.float64(others[f]) + phi
        if v < min_lo:
            v = min_lo
        others[f] = np.float32(v)
        if semantic:
            occupancy[f] = _occupancy(classes, lodds, others, f)

    # ---- local map (build_local): per voxel, its points in their original order (a stable
    # counting sort, by chunks of points: chunk b's points of a voxel follow chunk b - 1's),
    # summed slot by slot as numpy's per-slot bincount does. The sort moves the points'
    # classes and probabilities (read in pixel order, written grouped by voxel), so the voxel
    # pass reads them in sequence.
    n = voxels.shape[0]
    k = obs_cls.shape[1]
    n_points = local_index.shape[0]
    chunks = max(1, min(_SORT_CHUNKS, n_points // _SORT_CHUNK_MIN, _SORT_CELLS // max(n, 1)))
    per = (n_points + chunks - 1) // chunks
    fill = np.zeros((chunks, n), dtype=np.int64)
    for b in prange(chunks):
        for p in range(b * per, min(n_points, (b + 1) * per)):
            fill[b, local_index[p]] += 1
    counts = np.zeros(n, dtype=np.int64)
    start = np.zeros(n + 1, dtype=np.int64)
    for m in range(n):
        at = start[m]
        for b in range(chunks):
            c = fill[b, m]
            fill[b, m] = at
            at += c
        counts[m] = at - start[m]
        start[m + 1] = at
    cls_sorted = np.empty((n_points, k), dtype=obs_cls.dtype)
    p_sorted = np.empty((n_points, k), dtype=obs_p.dtype)
    for b in prange(chunks):
        for p in range(b * per, min(n_points, (b + 1) * per)):
            m = local_index[p]
            t = fill[b, m]
            fill[b, m] = t + 1
            q = pixels[p]
            for j in range(k):
                cls_sorted[t, j] = obs_cls[q, j]
                p_sorted[t, j] = obs_p[q, j]
    # the voxels in blocks, in parallel (each leaf is one voxel's: disjoint writes)
    for b in prange(blocks(n, _VOXEL_BLOCK)):
        _local_voxels(classes, lodds, others, occupancy, voxels, start, counts, cls_sorted,
                      p_sorted, span, psi, phi, theta, min_lo, max_lo, prob_min, bayes,
                      printed, semantic, b * _VOXEL_BLOCK, min(n, (b + 1) * _VOXEL_BLOCK))

def _local_voxels(classes, lodds, others, occupancy, voxels, start, counts, obs_cls, obs_p, span,
                  psi, phi, theta, min_lo, max_lo, prob_min, bayes, printed, semantic, first,
                  last):
    """The local node and leaf update of local voxels ``first`` to ``last`` (their points'
    classes and probabilities: rows ``start[m]`` to ``start[m + 1]`` of ``obs_cls`` and
    ``obs_p``), with their own scratch buffers."""
    k = obs_cls.shape[1]
    part = np.zeros((k, span))
    used = np.zeros(span, dtype=np.bool_)
    touched = np.empty(span, dtype=np.int64)
    keys6 = np.empty(6)
    rank6 = np.empty(6, dtype=np.int64)
    keys4 = np.empty(4)
    rank4 = np.empty(4, dtype=np.int64)
    cand_cls = np.empty(6, dtype=np.int64)
    cand_lo = np.empty(6)
    cand_ok = np.empty(6, dtype=np.bool_)
    loc_cls = np.empty(3, dtype=np.int64)
    loc_lo = np.empty(3, dtype=np.float32)
    best_c = np.empty(3, dtype=np.int64)
    best_v = np.empty(3)
    kept = np.zeros(3)
    for m in range(first, last):
        n_touched = 0
        # each (slot, class) sum runs over the voxel's points in their order, as bincount's
        for t in range(start[m], start[m + 1]):
            for j in range(k):
                c = obs_cls[t, j]
                w = np.float64(obs_p[t, j])
                if c >= 0 and w > 0:
                    part[j, c] += w
                    if not used[c]:
                        used[c] = True
                        touched[n_touched] = c
                        n_touched += 1
        # top 3 classes of the mean, ties to the smaller class id; classes whose mean is 0
        # are never kept, so only the touched ones compete
        cnt = np.float64(max(counts[m], 1))
        filled = 0
        for u in range(n_touched):
            c = touched[u]
            total_c = 0.0
            for j in range(k):
                total_c += part[j, c]
                part[j, c] = 0.0
            used[c] = False
            v = total_c / cnt
            pos = filled
            while pos > 0 and (best_v[pos - 1] < v or
                               (best_v[pos - 1] == v and best_c[pos - 1] > c)):
                pos -= 1
            if pos < 3:
                last = min(filled, 2)
                for t in range(last, pos, -1):
                    best_v[t] = best_v[t - 1]
                    best_c[t] = best_c[t - 1]
                best_v[pos] = v
                best_c[pos] = c
                if filled < 3:
                    filled += 1
        g = voxels[m]
        if bayes:  # eq. 7 takes the majority class only
            y = best_c[0] if filled > 0 and best_v[0] > 0 else -1
            _observe(classes, lodds, others, g, y, psi, phi, min_lo, max_lo, cand_cls,
                     cand_lo, cand_ok, keys4, rank4)
            if semantic:
                occupancy[g] = _occupancy(classes, lodds, others, g)
            continue
        for s in range(3):
            if s < filled and best_v[s] > 0:
                loc_cls[s] = best_c[s]
                pv = best_v[s]
            else:
                loc_cls[s] = -1
                pv = 0.0
            kept[s] = pv
            if loc_cls[s] >= 0:
                lo = psi + math.log(max(pv, prob_min))
                loc_lo[s] = np.float32(_clip(lo, min_lo, max_lo))
            else:
                loc_lo[s] = np.float32(0.0)
        # numpy's sum along a row of 3, as the reference takes it (local_map: out_p.sum(axis=1)):
        # left to right (numpy 2.4 here; tests/baselines/test_classic_semantic_kernels.py checks
        # that order). The earlier kept[0] + (kept[1] + kept[2]) differed in 17 % of rows.
        total = (kept[0] + kept[1]) + kept[2]
        rest = max(1.0 - total, prob_min)
        loc_ot = np.float32(_clip(psi + math.log(rest), min_lo, max_lo))

        if classes[g, 0] < 0 and classes[g, 1] < 0 and classes[g, 2] < 0:
            # first semantic observation: the local node
            for s in range(3):
                classes[g, s] = loc_cls[s]
                lodds[g, s] = loc_lo[s]
            others[g] = loc_ot
            if semantic:
                occupancy[g] = _occupancy(classes, lodds, others, g)
            continue

        # ---- Algorithm 1 (merge_algorithm1 -> _merge)
        n_z = 0
        for s in range(3):
            if classes[g, s] >= 0:
                n_z += 1
        c_in_g = np.zeros(3, dtype=np.bool_)
        g_in_c = np.zeros(3, dtype=np.bool_)
        cl_for_g = np.zeros(3)
        for i in range(3):
            for j in range(3):
                if classes[g, i] >= 0 and loc_cls[j] >= 0 and classes[g, i] == loc_cls[j]:
                    g_in_c[i] = True
                    c_in_g[j] = True
        for j in range(3):
            if loc_cls[j] >= 0 and not c_in_g[j]:
                n_z += 1
        for i in range(3):
            acc = 0.0
            for j in range(3):
                if classes[g, i] >= 0 and loc_cls[j] >= 0 and classes[g, i] == loc_cls[j]:
                    acc += np.float64(loc_lo[j])
                else:
                    acc += 0.0
            cl_for_g[i] = acc
        punish = theta * math.log1p(np.float64(n_z))
        g_ot = np.float64(others[g])
        delta_g = g_ot - punish
        delta_c = np.float64(loc_ot) - punish
        for i in range(3):
            gl = np.float64(lodds[g, i])
            cand_cls[i] = classes[g, i]
            cand_ok[i] = classes[g, i] >= 0
            if g_in_c[i]:
                cand_lo[i] = (gl + cl_for_g[i]) / 2.0
            else:
                cand_lo[i] = (gl + (delta_g if printed else delta_c)) / 2.0
        for j in range(3):
            cand_cls[3 + j] = loc_cls[j]
            cand_ok[3 + j] = loc_cls[j] >= 0 and not c_in_g[j]
            cand_lo[3 + j] = (np.float64(loc_lo[j]) + (delta_c if printed else delta_g)) / 2.0
        for i in range(6):
            keys6[i] = -cand_lo[i] if cand_ok[i] else np.inf
        _rank(keys6, 6, rank6)
        # log-sum-exp of the candidates ranked 4..6 that are valid
        top = -np.inf
        for r in range(3, 6):
            i = rank6[r]
            if cand_ok[i] and cand_lo[i] > top:
                top = cand_lo[i]
        safe = top if np.isfinite(top) else 0.0
        # numpy sums all six (masked ones are exp(-inf) = 0): the first plus the sequential
        # sum of the other five
        terms = np.zeros(6)
        for r in range(3, 6):
            i = rank6[r]
            if cand_ok[i]:
                terms[i] = math.exp(cand_lo[i] - safe)
        tail = 0.0
        for i in range(1, 6):
            tail += terms[i]
        acc = terms[0] + tail
        lse = (math.log(acc) if acc > 0 else -np.inf) + safe
        new_ot = _clip(_logaddexp((delta_g + delta_c) / 2.0, lse), min_lo, max_lo)
        # _state: top 3 of the clipped values
        for i in range(6):
            cand_lo[i] = _clip(cand_lo[i], min_lo, max_lo)
            keys6[i] = -cand_lo[i] if cand_ok[i] else np.inf
        _rank(keys6, 6, rank6)
        _store_ranked(classes, lodds, others, g, cand_cls, cand_lo, cand_ok, rank6, new_ot)
        if semantic:
            occupancy[g] = _occupancy(classes, lodds, others, g)



if numba is not None:
    _opts = {"cache": True, "nogil": True}
    _local_voxels = numba.njit(**_opts)(_local_voxels)
    _logaddexp = numba.njit(**_opts)(_logaddexp)
    _clip = numba.njit(**_opts)(_clip)
    _rank = numba.njit(**_opts)(_rank)
    _occupancy = numba.njit(**_opts)(_occupancy)
    _store_ranked = numba.njit(**_opts)(_store_ranked)
    _observe = numba.njit(**_opts)(_observe)
    frame_update = numba.njit(parallel=True, **_opts)(_frame_update)
else:  # pragma: no cover
    frame_update = None
