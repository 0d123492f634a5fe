"""Compiled (numba) frame update of the ``multiclass-bayes`` payloads.

One pass per voxel instead of numpy's whole-array passes, doing exactly what the numpy path in
:mod:`evsmap.updaters.multiclass_bayes` does with :func:`evsmap.mapping.fusion.mcb_miss`,
:func:`~evsmap.mapping.fusion.build_local` and :func:`~evsmap.mapping.fusion.merge_algorithm1`,
operation for operation in the same float32/float64 types and order (sums in the same order,
stable top-3 selection, numpy's ``logaddexp``), so both give the same stored ``int8`` steps; the
tests compare them frame by frame. Only the dense local-map case is compiled (voxels x classes up
to ``fusion._DENSE_LIMIT``); the caller falls back to numpy beyond it.
"""

from __future__ import annotations

import math

import numpy as np

try:
    import numba
except ImportError:  # pragma: no cover
    numba = None

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


def _quantize(value32, q, steps):
    s = np.rint(np.float64(value32) / q)
    if s > steps:
        s = np.float64(steps)
    elif s < -steps:
        s = -np.float64(steps)
    return np.int8(s)


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


def _frame_update(classes, lodds, others, free, voxels, local_index, pixels, obs_cls, obs_p,
                  span, q, steps, psi, phi, theta, min_lo, max_lo, prob_min):
    """``obs_cls`` / ``obs_p``: the observation's (H*W, k) classes and probabilities; point ``p``
    is pixel ``pixels[p]`` and lies in local voxel ``local_index[p]`` (map leaf
    ``voxels[local_index[p]]``)."""
    q32 = np.float32(q)
    # ---- rays: fuseObsFree on traversed voxels holding semantics (mcb_miss)
    for f in free:
        if classes[f, 0] < 0:
            continue
        for s in range(3):
            if classes[f, s] >= 0:
                v = np.float64(np.float32(lodds[f, s]) * q32) + phi
                if v < min_lo:
                    v = min_lo
                lodds[f, s] = _quantize(np.float32(v), q, steps)
            else:
                lodds[f, s] = _quantize(np.float32(0.0), q, steps)
        v = np.float64(np.float32(others[f]) * q32) + phi
        if v < min_lo:
            v = min_lo
        others[f] = _quantize(np.float32(v), q, steps)

    # ---- local map (build_local): per voxel, its points in their original order (a stable
    # counting sort), summed slot by slot as numpy's per-slot bincount does
    n = voxels.shape[0]
    k = obs_cls.shape[1]
    n_points = local_index.shape[0]
    counts = np.zeros(n, dtype=np.int64)
    for p in range(n_points):
        counts[local_index[p]] += 1
    start = np.zeros(n + 1, dtype=np.int64)
    for m in range(n):
        start[m + 1] = start[m] + counts[m]
    fill = start[:n].copy()
    members = np.empty(n_points, dtype=np.int64)
    for p in range(n_points):
        members[fill[local_index[p]]] = p
        fill[local_index[p]] += 1
    part = np.zeros((k, span))
    used = np.zeros(span, dtype=np.bool_)
    touched = np.empty(span, dtype=np.int64)
    keys6 = np.empty(6)
    rank6 = np.empty(6, dtype=np.int64)
    cand_cls = np.empty(6, dtype=np.int64)
    cand_lo = np.empty(6)
    cand_ok = np.empty(6, dtype=np.bool_)
    loc_cls = np.empty(3, dtype=np.int64)
    loc_lo = np.empty(3, dtype=np.float32)
    best_c = np.empty(3, dtype=np.int64)
    best_v = np.empty(3)
    for m in range(n):
        n_touched = 0
        for j in range(k):
            for t in range(start[m], start[m + 1]):
                p = pixels[members[t]]
                c = obs_cls[p, j]
                w = np.float64(obs_p[p, j])
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
        kept = np.zeros(3)
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
        # numpy's sum along a row: the first element plus the (sequential) sum of the others
        total = kept[0] + ((0.0 + kept[1]) + kept[2])
        rest = max(1.0 - total, prob_min)
        loc_ot = np.float32(_clip(psi + math.log(rest), min_lo, max_lo))

        g = voxels[m]
        if classes[g, 0] < 0 and classes[g, 1] < 0 and classes[g, 2] < 0:
            # first semantic observation: the local node
            for s in range(3):
                classes[g, s] = loc_cls[s]
                lodds[g, s] = _quantize(loc_lo[s], q, steps)
            others[g] = _quantize(loc_ot, q, steps)
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
        g_ot = np.float64(np.float32(others[g]) * q32)
        delta_g = g_ot - punish
        delta_c = np.float64(loc_ot) - punish
        for i in range(3):
            gl = np.float64(np.float32(lodds[g, i]) * q32)
            cand_cls[i] = classes[g, i]
            cand_ok[i] = classes[g, i] >= 0
            if g_in_c[i]:
                cand_lo[i] = (gl + cl_for_g[i]) / 2.0
            else:
                cand_lo[i] = (gl + delta_c) / 2.0
        for j in range(3):
            cand_cls[3 + j] = loc_cls[j]
            cand_ok[3 + j] = loc_cls[j] >= 0 and not c_in_g[j]
            cand_lo[3 + j] = (np.float64(loc_lo[j]) + delta_g) / 2.0
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
        for s in range(3):
            i = rank6[s]
            if cand_ok[i]:
                classes[g, s] = cand_cls[i]
                lodds[g, s] = _quantize(np.float32(cand_lo[i]), q, steps)
            else:
                classes[g, s] = -1
                lodds[g, s] = _quantize(np.float32(0.0), q, steps)
        others[g] = _quantize(np.float32(new_ot), q, steps)


if numba is not None:
    _opts = {"cache": True, "nogil": True}
    _logaddexp = numba.njit(**_opts)(_logaddexp)
    _quantize = numba.njit(**_opts)(_quantize)
    _clip = numba.njit(**_opts)(_clip)
    _rank = numba.njit(**_opts)(_rank)
    frame_update = numba.njit(**_opts)(_frame_update)
else:  # pragma: no cover
    frame_update = None
