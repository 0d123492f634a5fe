"""semantic_slam's semantic fusion rules ([14] in EVSMaP, ``SemanticsMax`` /
``SemanticsBayesian``), vectorised over M voxels: the rule set of the ``classwise`` front
end of ``classic-semantic``. Only the baseline uses them, so they live here, not in
evsmap.

* :func:`fuse_max` - same class: confidence ``(c1 + c2) / 2``; different classes: keep the more
  confident (the second on a tie, as ``s1 > s2 ? s1 : s2``) and multiply its confidence by 0.9.
* :func:`fuse_bayes` - 3 slots, ALPHA 0.8, EPSILON 0.001. Residuals ``o = 1 - sum(conf)``, floored
  at EPSILON. Walking the first set's classes in slot order, each one missing from the second set
  gets confidence ``ALPHA * o2`` there and ``o2 -= ALPHA * o2`` (so a second missing class gets
  ``0.8 * 0.2 * o2``); then each of the second set's classes missing from the first, in slot
  order, is appended with ``ALPHA * o1`` and ``o1 -= ALPHA * o1``. Posterior of every class is
  ``conf1 * conf2``, of the rest ``o1 * o2`` (the decremented residuals); divide by the sum, floor
  every class at EPSILON, keep the 3 most confident (stable sort: on ties the earlier candidate,
  first set before appended classes, wins; C++ ``std::sort`` leaves that order unspecified).
  A voxel without semantics on one side takes the other side unchanged (``updateNodeSemantics``
  copies an observation into an empty voxel; inner nodes skip children without semantics).
  Confidences are computed in float64 and returned as float32 (the C++ code uses float).
"""

from __future__ import annotations

import numpy as np

from evsmap.mapping.fusion.slots import EMPTY, SLOTS, match_slots, pad_slots, top_slots

FUSION_DECAY = 0.9
"""Max fusion: confidence factor on disagreement."""

ALPHA = 0.8
"""Bayesian rule: share of the residual given to a newly seen class."""

EPSILON = 0.001
"""Bayesian (semantic_slam): floor of confidences and residuals."""


def fuse_max(c1: np.ndarray, p1: np.ndarray, c2: np.ndarray,
             p2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``SemanticsMax::semanticFusion`` for M voxels: ``(class, confidence)`` each (M,).

    Same class: confidence ``(p1 + p2) / 2``. Different: ``p1 > p2 ? 1 : 2`` is kept, confidence
    times 0.9. A side with class -1 (no semantics) yields the other side unchanged.
    """
    c1 = np.asarray(c1)
    c2 = np.asarray(c2)
    p1 = np.asarray(p1, dtype=np.float64)
    p2 = np.asarray(p2, dtype=np.float64)
    same = c1 == c2
    first = p1 > p2
    cls = np.where(same | first, c1, c2)
    conf = np.where(same, (p1 + p2) / 2.0, np.where(first, p1, p2) * FUSION_DECAY)
    e1, e2 = c1 < 0, c2 < 0
    cls = np.where(e1, c2, np.where(e2, c1, cls))
    conf = np.where(e1, p2, np.where(e2, p1, conf))
    return cls.astype(np.int16), conf.astype(np.float32)



def fuse_bayes(classes1: np.ndarray, conf1: np.ndarray, classes2: np.ndarray,
               conf2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``SemanticsBayesian::semanticFusion`` for M voxels (see the module notes).

    Args:
        classes1, classes2: integer (M, 3) class ids, -1 for empty slots.
        conf1, conf2: (M, 3) confidences (0 in empty slots).

    Returns:
        ``(classes int16 (M, 3), conf float32 (M, 3))``, most confident first; slots beyond the
        number of distinct classes are empty (-1, 0).
    """
    a = np.asarray(classes1).astype(np.int64)
    b = np.asarray(classes2).astype(np.int64)
    fa = np.asarray(conf1, dtype=np.float64)
    fb = np.asarray(conf2, dtype=np.float64)
    av, bv = np.asarray(a >= 0), np.asarray(b >= 0)
    fa = np.where(av, fa, 0.0)
    fb = np.where(bv, fb, 0.0)
    m, na = a.shape
    nb = b.shape[1]
    o1 = np.maximum(1.0 - fa.sum(axis=1), EPSILON)
    o2 = np.maximum(1.0 - fb.sum(axis=1), EPSILON)
    match = match_slots(a, av, b, bv)
    a_in_b = np.asarray(match.any(axis=2))
    b_in_a = np.asarray(match.any(axis=1))
    fb_for_a = np.where(match, fb[:, None, :], 0.0).sum(axis=2)

    # Candidates: a's slots, then b's classes that a lacks; first and second confidences.
    first = np.zeros((m, na + nb))
    second = np.zeros((m, na + nb))
    valid = np.concatenate([av, bv & ~b_in_a], axis=1)
    cls = np.concatenate([a, b], axis=1)
    for i in range(na):
        missing = av[:, i] & ~a_in_b[:, i]
        first[:, i] = fa[:, i]
        second[:, i] = np.where(missing, ALPHA * o2, fb_for_a[:, i])
        o2 = np.where(missing, o2 - ALPHA * o2, o2)
    for j in range(nb):
        new = bv[:, j] & ~b_in_a[:, j]
        first[:, na + j] = np.where(new, ALPHA * o1, 0.0)
        second[:, na + j] = fb[:, j]
        o1 = np.where(new, o1 - ALPHA * o1, o1)

    post = np.where(valid, first * second, 0.0)
    total = o1 * o2 + post.sum(axis=1)
    post = np.maximum(post / total[:, None], EPSILON)
    idx, _ = top_slots(post, valid, SLOTS)
    out_valid = np.take_along_axis(valid, idx, axis=1)
    out_cls = np.where(out_valid, np.take_along_axis(cls, idx, axis=1), EMPTY)
    out_conf = np.where(out_valid, np.take_along_axis(post, idx, axis=1), 0.0)

    # A side without semantics: the other side unchanged.
    set_a, set_b = np.asarray(av.any(axis=1)), np.asarray(bv.any(axis=1))
    copy_b = ~set_a
    copy_a = set_a & ~set_b
    out_cls = np.where(copy_b[:, None], pad_slots(b, SLOTS, EMPTY), out_cls)
    out_conf = np.where(copy_b[:, None], pad_slots(fb, SLOTS, 0.0), out_conf)
    out_cls = np.where(copy_a[:, None], pad_slots(a, SLOTS, EMPTY), out_cls)
    out_conf = np.where(copy_a[:, None], pad_slots(fa, SLOTS, 0.0), out_conf)
    return out_cls.astype(np.int16), out_conf.astype(np.float32)


