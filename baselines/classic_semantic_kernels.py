"""Compiled (numba) frame update of ``classic-semantic``'s ``classwise`` front end.

It does exactly what the numpy reference :func:`baselines.classic_semantic.fuse_frame` does
with :func:`~baselines.classic_semantic.voxel_distributions` (the mean of the points' top-k
distributions, through ``evsmap.mapping.fusion.build_local``), semantic_slam's rules
:func:`baselines.semantic_slam_fusion.fuse_bayes` / :func:`~baselines.semantic_slam_fusion.fuse_max`
and ``evsmap.mapping.fusion.average_frame_colours``, in passes over the frame's points in their
order (counts, colour sums, then the class sums slot by slot, as ``bincount`` adds them) and
one pass over the hit voxels, instead of numpy's many whole-array passes. Same float64
operations in the same order (row sums left to right, as numpy reduces a C-ordered row), same
stable rankings (the mean's classes: ties to the smaller class id; the fused candidates: ties
to the earlier one), same float32 results: both paths store the same arrays, and the tests
compare them. Only the dense local map is compiled (voxels x classes up to
``fusion.DENSE_LIMIT``, the case ``build_local`` sums densely, with the same two tables);
beyond it :func:`frame_update` changes nothing and says so, and the caller runs the reference.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from baselines.semantic_slam_fusion import ALPHA, EPSILON, FUSION_DECAY

_WHITE = 255


@njit(cache=True, nogil=True)
def _insert_top3(best_c, best_v, filled, c, v):
    """Insert class ``c`` with mean ``v`` into the descending top 3 (``filled`` entries so far);
    classes come in ascending order, so an equal mean stays behind the smaller class, as in a
    stable argsort of ``-mean``. Returns the new count."""
    pos = filled
    while pos > 0 and best_v[pos - 1] < v:
        pos -= 1
    if pos >= 3:
        return filled
    for t in range(min(filled, 2), pos, -1):
        best_c[t] = best_c[t - 1]
        best_v[t] = best_v[t - 1]
    best_c[pos] = c
    best_v[pos] = v
    return min(filled + 1, 3)


@njit(cache=True, nogil=True)
def _bayes_scratch():
    """Work arrays of :func:`_fuse_bayes`, allocated once a frame: a's classes, a's / b's
    confidences, the b confidence matched to each a slot, a-in-b and b-in-a flags, the 6
    candidates' classes, validity, posteriors and whether each is taken."""
    return (np.empty(3, np.int64), np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3, np.bool_),
            np.zeros(3, np.bool_), np.empty(6, np.int64), np.zeros(6, np.bool_), np.zeros(6),
            np.zeros(6, np.bool_))


@njit(cache=True, nogil=True)
def _fuse_bayes(cls, conf, g, b, fb32, scratch):
    """``fuse_bayes`` of leaf ``g`` (``cls`` / ``conf``: the map's (N, 3) slots) with the
    observation ``b`` (3 classes, -1 empty) / ``fb32`` (float32 confidences), in place."""
    a, fa, fb, fb_for_a, a_in_b, b_in_a, cand, valid, post, taken = scratch
    set_a = False
    set_b = False
    for i in range(3):
        a[i] = cls[g, i]
        fa[i] = np.float64(conf[g, i]) if a[i] >= 0 else 0.0
        fb[i] = np.float64(fb32[i]) if b[i] >= 0 else 0.0
        set_a = set_a or a[i] >= 0
        set_b = set_b or b[i] >= 0
    if not (set_a and set_b):  # a side without semantics: the other side unchanged
        for i in range(3):
            cls[g, i] = a[i] if set_a else b[i]
            conf[g, i] = np.float32(fa[i] if set_a else fb[i])
        return
    o1 = max(1.0 - ((fa[0] + fa[1]) + fa[2]), EPSILON)
    o2 = max(1.0 - ((fb[0] + fb[1]) + fb[2]), EPSILON)
    for i in range(3):
        a_in_b[i] = False
        b_in_a[i] = False
    for i in range(3):
        acc = 0.0
        for j in range(3):
            hit = a[i] >= 0 and b[j] >= 0 and a[i] == b[j]
            a_in_b[i] = a_in_b[i] or hit
            b_in_a[j] = b_in_a[j] or hit
            # numpy's row sum: (t0 + t1) + t2, the first term taken as it is
            t = fb[j] if hit else 0.0
            acc = t if j == 0 else acc + t
        fb_for_a[i] = acc
    # candidates: a's slots, then b's classes that a lacks
    for i in range(6):
        post[i] = 0.0
        taken[i] = False
    for i in range(3):
        cand[i] = a[i]
        valid[i] = a[i] >= 0
        if valid[i] and not a_in_b[i]:
            second = ALPHA * o2
            o2 = o2 - ALPHA * o2
        else:
            second = fb_for_a[i]
        if valid[i]:
            post[i] = fa[i] * second
    for j in range(3):
        cand[3 + j] = b[j]
        valid[3 + j] = b[j] >= 0 and not b_in_a[j]
        if valid[3 + j]:
            first = ALPHA * o1
            o1 = o1 - ALPHA * o1
            post[3 + j] = first * fb[j]
    acc = post[0]
    for i in range(1, 6):
        acc = acc + post[i]
    total = o1 * o2 + acc
    for i in range(6):
        post[i] = max(post[i] / total, EPSILON)
    # the 3 most confident valid candidates, the earlier one on ties
    for s in range(3):
        pick = -1
        for i in range(6):
            if valid[i] and not taken[i] and (pick < 0 or post[i] > post[pick]):
                pick = i
        if pick < 0:
            cls[g, s] = -1
            conf[g, s] = np.float32(0.0)
        else:
            taken[pick] = True
            cls[g, s] = cand[pick]
            conf[g, s] = np.float32(post[pick])


@njit(cache=True, nogil=True)
def _fuse_max(cls, conf, g, c2, p2_32):
    """``fuse_max`` of leaf ``g``'s single slot with the observation (``c2``, float32
    ``p2_32``), in place."""
    c1 = np.int64(cls[g, 0])
    p1 = np.float64(conf[g, 0])
    p2 = np.float64(p2_32)
    if c1 < 0:
        c, p = c2, p2
    elif c2 < 0:
        c, p = c1, p1
    elif c1 == c2:
        c, p = c1, (p1 + p2) / 2.0
    elif p1 > p2:
        c, p = c1, p1 * FUSION_DECAY
    else:
        c, p = c2, p2 * FUSION_DECAY
    cls[g, 0] = c
    conf[g, 0] = np.float32(p)


@njit(cache=True, nogil=True)
def frame_update(sem_classes, sem_conf, rgb, voxels, local, pixels, obs_cls, obs_p, colours,
                 use_rgb, bayes, prob_min, dense_limit):
    """One frame's colours and semantics on its hit voxels, in place.

    Args:
        sem_classes, sem_conf, rgb: the map's leaf payloads (``int16`` (N, S), ``float32``
            (N, S), ``uint8`` (N, 3); S = 3 for ``bayes``, else 1).
        voxels: map rows of the distinct hit voxels; ``local``: each point's position among
            them; ``pixels``: each point's flat pixel index.
        obs_cls, obs_p: the observation's (H*W, k) top-k classes and probabilities.
        colours: the frame's (H*W, 3) colours (used when ``use_rgb``).
        prob_min: ``build_local``'s probability floor; ``dense_limit``: its dense-table limit.

    Returns:
        False, changing nothing, where the local map is beyond the dense limit (voxels x
        (largest class of the points + 1)); else True.
    """
    n = voxels.shape[0]
    n_points = local.shape[0]
    k = obs_cls.shape[1]
    # points, in their order: counts and colour sums per voxel (bincount's), largest class
    count = np.zeros(n, np.int64)
    colour_sum = np.zeros((n, 3))
    span = 0
    for p in range(n_points):
        m = local[p]
        px = pixels[p]
        count[m] += 1
        if use_rgb:
            for ch in range(3):
                colour_sum[m, ch] += np.float64(colours[px, ch])
        for j in range(k):
            span = max(span, np.int64(obs_cls[px, j]) + 1)
    if span > 0 and n * span > dense_limit:
        return False
    # build_local's dense sums: slot by slot, a (voxel, class) table summed in point order and
    # then added to the total
    width = max(span, 1)
    sums = np.zeros((n, width))
    part = np.zeros((n, width))
    for j in range(k):
        for p in range(n_points):
            px = pixels[p]
            c = np.int64(obs_cls[px, j])
            w = np.float64(obs_p[px, j])
            if c >= 0 and w > 0:
                part[local[p], c] += w
        for m in range(n):
            for c in range(width):
                sums[m, c] += part[m, c]
                part[m, c] = 0.0

    best_c = np.empty(3, np.int64)
    best_v = np.zeros(3)
    obs_c = np.empty(3, np.int64)
    obs_f = np.zeros(3, np.float32)
    scratch = _bayes_scratch()
    for m in range(n):
        g = voxels[m]
        points = np.float64(max(count[m], 1))
        if use_rgb:  # averageNodeColor with the floored mean colour of the points
            is_set = rgb[g, 0] != _WHITE or rgb[g, 1] != _WHITE or rgb[g, 2] != _WHITE
            for ch in range(3):
                mean = np.int64(math.floor(colour_sum[m, ch] / points))
                rgb[g, ch] = np.uint8((np.int64(rgb[g, ch]) + mean) // 2 if is_set else mean)
        # the top 3 classes of the mean (classes whose mean is 0 are never kept)
        filled = 0
        for c in range(width):
            if sums[m, c] > 0:
                filled = _insert_top3(best_c, best_v, filled, c, sums[m, c] / points)
        # the observation as build_local's node stores it: exp of the float32 log-probability
        for s in range(3):
            if s < filled and best_v[s] > 0:
                obs_c[s] = best_c[s]
                lo = np.float32(math.log(max(best_v[s], prob_min)))
                obs_f[s] = np.float32(math.exp(np.float64(lo)))
            else:
                obs_c[s] = -1
                obs_f[s] = np.float32(0.0)
        if bayes:
            _fuse_bayes(sem_classes, sem_conf, g, obs_c, obs_f, scratch)
        else:
            _fuse_max(sem_classes, sem_conf, g, obs_c[0], obs_f[0])
    return True
