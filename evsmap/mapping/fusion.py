"""Per-voxel colour and semantic fusion rules, vectorised over arrays of voxels.

Every function is pure: it takes struct-of-arrays states for M voxels and returns new arrays; no
Python loop runs per voxel (loops over the 3 semantic slots only). Empty semantic slots hold class
``-1`` (:data:`EMPTY`); a voxel whose slots are all empty has no semantics yet.

Colour (OctoMap ``ColorOcTree``)
--------------------------------
* :func:`integrate_color` - ``ColorOcTree::integrateNodeColor``: with the node's occupancy
  probability p, each channel becomes ``(uint8)(prev * p + new * (0.99 - p))`` (C++ cast:
  truncation), or the new colour when the node had none.
* :func:`average_node_color` - ``averageNodeColor`` (what semantic_slam uses for leaves):
  ``(prev + new) / 2`` in integer arithmetic.
* :func:`average_color` - ``getAverageChildColor`` for inner nodes: integer mean over the children
  that have a colour, white (255, 255, 255) when none has.
* OctoMap's convention is that a colour is "set" when it is not pure white (:func:`color_is_set`).

Classic semantic fusion ([14], semantic_slam ``SemanticsMax`` / ``SemanticsBayesian``)
---------------------------------------------------------------------------------------
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

Multi-class Bayesian mapping (EVSMaP eqs. 5-10, SSMI ``SemanticsLogOdds``)
--------------------------------------------------------------------------
A voxel holds up to 3 classes with log-odds against "free" (eq. 5) plus the log-odds ``others`` of
all remaining classes, sorted most likely first (:class:`MCBState`). A voxel without classes keeps
its occupancy log-odds in ``others`` (0 = unknown). Derived quantities: occupancy log-odds
``L = log(exp(others) + sum_i exp(l_i))`` (:func:`mcb_occupancy`) and the class probabilities by
the softmax with free, whose log-odds is 0 (eq. 6, :func:`mcb_probabilities`).

* :func:`mcb_hit` (``fuseObs``): the observed class ``+= psi`` (capped at the maximum), the other
  stored classes ``+= phi`` (floored). A class not stored yet enters at
  ``others + log 0.8 + psi`` (the pre-update others) and ``others += log 0.2 + phi``; the 4 entries
  are sorted and the smallest is folded into others by log-sum-exp. Otherwise ``others += phi``.
  Finally others is clamped to [min, max]. A voxel without classes is initialised as in SSMI's
  ``initSemantics``: class ``log 0.1 + others + psi`` (clamped), others ``log 0.9 + others + phi``
  (floored). One deliberate difference: SSMI does not cap an entering class at the maximum; here
  it is capped so every stored log-odds stays within the clamps.
* :func:`mcb_miss` (``fuseObsFree``): every stored entry and others ``+= phi``, floored.
* Defaults psi = 1, phi = -0.1, clamps at probabilities 1e-4 / 0.9999 (log-odds -+9.21).
* :func:`merge_ssmi` - SSMI's ``semanticFusion`` of two nodes: a class absent from one node takes
  that node's ``others - log(#classes it misses + 1)``; values averaged; others averaged; top 3
  kept, the rest folded into others (log-sum-exp); here also clamped.

Algorithm 1 (EVSMaP, punishment value theta = 0.6)
---------------------------------------------------
:func:`merge_algorithm1` fuses a frame's local-map node C into the global-map node G. The reading
implemented, line by line (the printed lines are quoted):

1. "xi_G = 1 - SUM(zeta_G)", "xi_C = 1 - SUM(zeta_C)": xi is the node's *others* entry, the mass
   of every class not among its three. The map stores it, like zeta, as log-odds against free
   (eq. 5; the later lines "Delta_U = exp(...)", "exp(zeta_U(z)[i].logodds)", "xi_U = log(Delta_U)"
   only make sense in log-odds), so xi is read from the state rather than recomputed.
2. "Z = UNIQUECLASS(N_G, N_C)": the union of the classes stored in either node (empty slots are
   not classes).
3. "Delta_G = xi_G - theta log(1 + Size(Z))", "Delta_C = xi_C - theta log(1 + Size(Z))": taken
   literally, Size(Z) = |Z| (1..6) for both nodes. (SSMI subtracts, with weight 1, the log of
   1 + the number of classes that node misses.) Consequence: even two nodes with identical class
   sets lower their merged others by theta log 4 = 0.83.
4. "If z in N_G and z not in N_C then ... zeta_U(z) = (Delta_G + zeta_G(z)) / 2" and "If z in N_C
   and z not in N_G then ... zeta_U(z) = (Delta_C + zeta_C(z)) / 2": read with the Delta
   subscripts swapped. A class that C does not hold takes C's punished others as C's value:
   ``zeta_U(z) = (zeta_G(z) + Delta_C) / 2``, and likewise ``(zeta_C(z) + Delta_G) / 2``. As
   printed, the class would be averaged with the Delta of the node that *holds* it, so the node
   lacking it would have no say; the swapped reading is SSMI's rule and is what the text asks of
   theta: "we adjust the confidence levels of the others class for both nodes, ensuring the three
   highest probability semantic labels retained in the merged node represent classes shared by
   the two nodes".
5. "Else ... zeta_U(z) = (zeta_G(z) + zeta_C(z)) / 2": the two Ifs read as if / else-if / else,
   so this is the class held by both nodes.
6. "Descending sort on N_U with respect to zeta_U(z)": stable; on ties G's classes (slot order)
   come before C's.
7. "Delta_U = exp((Delta_G + Delta_C) / 2)", "For i > 3 do Delta_U += exp(zeta_U(z)[i].logodds)",
   "zeta_U(z)[3:end].Remove", "xi_U(z) = log(Delta_U)": classes after the third (1-based) are
   folded into the merged others by log-sum-exp with the mean of the two punished others.
8. Not in the algorithm: every output log-odds is clamped to [min, max], as SSMI does.

Local map of one frame (:func:`build_local`)
--------------------------------------------
A frame's points are aggregated into one node per voxel, as one soft hit: the voxel's class
distribution is the mean over its points of their top-k distributions (a class missing from a
point's top-k counts 0 for it; each point's residual mass goes to others), the top 3 classes are
kept and everything else (residuals and folded classes) is ``others``. The node is occupied with
log-odds ``hit`` (default psi): ``l_c = hit + log(pbar_c)``, ``others = hit + log(pbar_others)``
(probabilities floored at the minimum clamp probability), so its occupancy log-odds ``L`` is
exactly ``hit``. Averaging (rather than applying every point as a hit in sequence) makes the
node independent of the order and the number of points, the way OctoMap updates each voxel at
most once per scan.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

EMPTY = -1
"""Class id of an empty semantic slot."""

SLOTS = 3
"""Semantic slots per voxel (semantic_slam's NUM_SEMANTICS, SSMI's 3 classes + others)."""

FUSION_DECAY = 0.9
"""Max fusion: confidence factor on disagreement."""

ALPHA = 0.8
"""Bayesian (semantic_slam) and SSMI: share of the residual given to a newly seen class."""

EPSILON = 0.001
"""Bayesian (semantic_slam): floor of confidences and residuals."""

BETA = 0.1
"""SSMI ``initSemantics``: share given to the first class of a voxel without classes."""

PSI = 1.0
"""SSMI: log-odds added to the observed class on a hit."""

PHI = -0.1
"""SSMI: log-odds added to every other entry on a hit and to every entry on a miss."""

THETA = 0.6
"""EVSMaP Algorithm 1 punishment value."""

PROB_MIN, PROB_MAX = 1e-4, 0.9999
"""SSMI clamping probabilities."""

MIN_LOGODDS = math.log(PROB_MIN / (1.0 - PROB_MIN))
"""-9.21"""

MAX_LOGODDS = math.log(PROB_MAX / (1.0 - PROB_MAX))
"""+9.21"""

WHITE = 255


# ------------------------------------------------------------------------------------------
# colour
# ------------------------------------------------------------------------------------------
def color_is_set(rgb: np.ndarray) -> np.ndarray:
    """OctoMap's ``isColorSet``: any channel differs from 255 (pure white means "no colour")."""
    return np.any(np.asarray(rgb) != WHITE, axis=-1)


def integrate_color(prev_rgb: np.ndarray, prev_set: np.ndarray, occupancy: np.ndarray,
                    new_rgb: np.ndarray) -> np.ndarray:
    """``ColorOcTree::integrateNodeColor`` for M voxels.

    Args:
        prev_rgb: ``uint8`` (M, 3) current colours.
        prev_set: bool (M,) whether a colour was set (see :func:`color_is_set`).
        occupancy: (M,) occupancy probability of each node (``getOccupancy``).
        new_rgb: (M, 3) observed colours.

    Returns:
        ``uint8`` (M, 3): ``trunc(prev * p + new * (0.99 - p))`` per channel where a colour was
        set, else ``new_rgb``. Values are clipped to [0, 255] (C++ leaves p > 0.99 undefined).
    """
    prev = np.asarray(prev_rgb, dtype=np.float64)
    new = np.asarray(new_rgb)
    p = np.asarray(occupancy, dtype=np.float64)[:, None]
    mixed = np.trunc(prev * p + new.astype(np.float64) * (0.99 - p))
    mixed = np.clip(mixed, 0, 255).astype(np.uint8)
    return np.where(np.asarray(prev_set, dtype=bool)[:, None], mixed, new.astype(np.uint8))


def average_node_color(prev_rgb: np.ndarray, prev_set: np.ndarray,
                       new_rgb: np.ndarray) -> np.ndarray:
    """``averageNodeColor``: ``(prev + new) / 2`` (integer division) where a colour was set,
    else the new colour; ``uint8`` (M, 3)."""
    prev = np.asarray(prev_rgb).astype(np.int32)
    new = np.asarray(new_rgb).astype(np.int32)
    mean = ((prev + new) // 2).astype(np.uint8)
    return np.where(np.asarray(prev_set, dtype=bool)[:, None], mean, new.astype(np.uint8))


def average_color(children_rgb: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """``getAverageChildColor`` for M inner nodes.

    Args:
        children_rgb: ``uint8`` (M, n, 3) colours of up to n (8) children.
        mask: bool (M, n) children that exist and have a colour set.

    Returns:
        ``uint8`` (M, 3): per channel ``sum // count`` over the masked children (C++ int
        division), white where no child counts.
    """
    rgb = np.asarray(children_rgb).astype(np.int64)
    m = np.asarray(mask, dtype=bool)
    sums = np.where(m[..., None], rgb, 0).sum(axis=1)
    count = m.sum(axis=1)
    mean = sums // np.maximum(count, 1)[:, None]
    return np.where((count > 0)[:, None], mean, WHITE).astype(np.uint8)


# ------------------------------------------------------------------------------------------
# classic semantic fusion (semantic_slam)
# ------------------------------------------------------------------------------------------
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


def _match(a: np.ndarray, av: np.ndarray, b: np.ndarray, bv: np.ndarray) -> np.ndarray:
    """(M, na, nb) bool: slot i of a holds the same (valid) class as slot j of b."""
    return (a[:, :, None] == b[:, None, :]) & av[:, :, None] & bv[:, None, :]


def _top(values: np.ndarray, valid: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Indices (M, n) of the n largest valid values, stable (earlier candidate first on ties),
    and the rank order of all candidates (M, K)."""
    key = np.where(valid, -values, np.inf)
    order = np.argsort(key, axis=1, kind="stable")
    return order[:, :n], order


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
    av, bv = a >= 0, b >= 0
    fa = np.where(av, fa, 0.0)
    fb = np.where(bv, fb, 0.0)
    m, na = a.shape
    nb = b.shape[1]
    o1 = np.maximum(1.0 - fa.sum(axis=1), EPSILON)
    o2 = np.maximum(1.0 - fb.sum(axis=1), EPSILON)
    match = _match(a, av, b, bv)
    a_in_b = match.any(axis=2)
    b_in_a = match.any(axis=1)
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
    idx, _ = _top(post, valid, SLOTS)
    out_valid = np.take_along_axis(valid, idx, axis=1)
    out_cls = np.where(out_valid, np.take_along_axis(cls, idx, axis=1), EMPTY)
    out_conf = np.where(out_valid, np.take_along_axis(post, idx, axis=1), 0.0)

    # A side without semantics: the other side unchanged.
    set_a, set_b = av.any(axis=1), bv.any(axis=1)
    copy_b = ~set_a
    copy_a = set_a & ~set_b
    out_cls = np.where(copy_b[:, None], _pad(b, SLOTS, EMPTY), out_cls)
    out_conf = np.where(copy_b[:, None], _pad(fb, SLOTS, 0.0), out_conf)
    out_cls = np.where(copy_a[:, None], _pad(a, SLOTS, EMPTY), out_cls)
    out_conf = np.where(copy_a[:, None], _pad(fa, SLOTS, 0.0), out_conf)
    return out_cls.astype(np.int16), out_conf.astype(np.float32)


def _pad(x: np.ndarray, n: int, fill: float) -> np.ndarray:
    """First n columns of x, padded with ``fill`` when x has fewer."""
    if x.shape[1] >= n:
        return x[:, :n]
    pad = np.full((x.shape[0], n - x.shape[1]), fill, dtype=x.dtype)
    return np.concatenate([x, pad], axis=1)


# ------------------------------------------------------------------------------------------
# multi-class Bayesian (SSMI / EVSMaP)
# ------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class MCBState:
    """Multi-class Bayesian semantics of M voxels (struct of arrays).

    Attributes:
        classes: ``int16`` (M, 3) class ids, most likely first, -1 in empty slots (which come
            last).
        logodds: ``float32`` (M, 3) log-odds of each class against free; 0 in empty slots.
        others: ``float32`` (M,) log-odds of all other classes against free; for a voxel without
            classes, its occupancy log-odds.
    """

    classes: np.ndarray
    logodds: np.ndarray
    others: np.ndarray

    def __post_init__(self) -> None:
        c = np.asarray(self.classes)
        lo = np.asarray(self.logodds)
        ot = np.asarray(self.others)
        if c.ndim != 2 or lo.shape != c.shape or ot.shape != c.shape[:1]:
            raise ValueError(f"MCBState needs classes (M, S), logodds (M, S) and others (M,); got "
                             f"{c.shape}, {lo.shape}, {ot.shape}")
        object.__setattr__(self, "classes", c.astype(np.int16, copy=False))
        object.__setattr__(self, "logodds", lo.astype(np.float32, copy=False))
        object.__setattr__(self, "others", ot.astype(np.float32, copy=False))

    def __len__(self) -> int:
        return int(self.classes.shape[0])

    @property
    def valid(self) -> np.ndarray:
        """(M, 3) bool: slots holding a class."""
        return self.classes >= 0

    @property
    def has_semantics(self) -> np.ndarray:
        """(M,) bool: voxels with at least one class."""
        return self.valid.any(axis=1)

    @classmethod
    def empty(cls, m: int, others: float = 0.0) -> MCBState:
        """M voxels without classes whose occupancy log-odds is ``others`` (0 = unknown)."""
        return cls(np.full((m, SLOTS), EMPTY, np.int16), np.zeros((m, SLOTS), np.float32),
                   np.full(m, others, np.float32))

    def take(self, index: np.ndarray) -> MCBState:
        """The voxels at ``index`` (any numpy index)."""
        return MCBState(self.classes[index], self.logodds[index], self.others[index])

    def equals(self, other: MCBState) -> np.ndarray:
        """(M,) bool: exactly equal classes, log-odds and others (pruning test)."""
        return (np.all(self.classes == other.classes, axis=1)
                & np.all(self.logodds == other.logodds, axis=1)
                & (self.others == other.others))


def _state(cls: np.ndarray, lo: np.ndarray, valid: np.ndarray, others: np.ndarray) -> MCBState:
    """Sort candidates (M, K) most likely first, keep 3, normalise empty slots."""
    idx, _ = _top(lo, valid, SLOTS)
    v = np.take_along_axis(valid, idx, axis=1)
    c = np.where(v, np.take_along_axis(cls, idx, axis=1), EMPTY)
    lo = np.where(v, np.take_along_axis(lo, idx, axis=1), 0.0)
    return MCBState(_pad(c, SLOTS, EMPTY), _pad(lo, SLOTS, 0.0), others)


def _logsumexp_masked(values: np.ndarray, mask: np.ndarray, axis: int) -> np.ndarray:
    """log(sum(exp(values[mask]))) along ``axis``; -inf where nothing is masked."""
    v = np.where(mask, values, -np.inf)
    top = np.max(v, axis=axis, keepdims=True)
    safe = np.where(np.isfinite(top), top, 0.0)
    with np.errstate(divide="ignore"):
        out = np.log(np.sum(np.exp(v - safe), axis=axis, keepdims=True)) + safe
    return np.squeeze(out, axis=axis)


def mcb_hit(state: MCBState, cls: np.ndarray, *, psi: float = PSI, phi: float = PHI,
            max_logodds: float = MAX_LOGODDS, min_logodds: float = MIN_LOGODDS) -> MCBState:
    """SSMI ``fuseObs`` (``initSemantics`` for voxels without classes): each voxel observed
    occupied with class ``cls[m]`` (M,) (>= 0). See the module notes."""
    cls = np.asarray(cls).astype(np.int64)
    if cls.shape != (len(state),):
        raise ValueError(f"mcb_hit needs one class per voxel ({len(state)}), got {cls.shape}")
    if cls.size and cls.min() < 0:
        raise ValueError("mcb_hit: observed classes must be >= 0")
    c = state.classes.astype(np.int64)
    lo = state.logodds.astype(np.float64)
    ot = state.others.astype(np.float64)
    valid = c >= 0
    match = valid & (c == cls[:, None])
    found = match.any(axis=1)
    lo_new = np.where(match, np.minimum(lo + psi, max_logodds),
                      np.maximum(lo + phi, min_logodds))
    lo_new = np.where(valid, lo_new, 0.0)
    entering = np.minimum(ot + math.log(ALPHA) + psi, max_logodds)
    others_new = np.where(found, ot + phi, ot + math.log(1.0 - ALPHA) + phi)

    cand_cls = np.concatenate([c, cls[:, None]], axis=1)
    cand_lo = np.concatenate([lo_new, entering[:, None]], axis=1)
    cand_valid = np.concatenate([valid, ~found[:, None]], axis=1)
    _, order = _top(cand_lo, cand_valid, SLOTS)
    # Fold the 4th entry (only when 3 classes were stored and a new one entered).
    fourth = order[:, SLOTS]
    fold = np.take_along_axis(cand_valid, fourth[:, None], axis=1)[:, 0]
    fold_lo = np.take_along_axis(cand_lo, fourth[:, None], axis=1)[:, 0]
    others_new = np.where(fold, np.logaddexp(others_new, fold_lo), others_new)
    others_new = np.clip(others_new, min_logodds, max_logodds)
    out = _state(cand_cls, cand_lo, cand_valid, others_new)

    # Voxels without classes: SSMI initSemantics.
    init = ~valid.any(axis=1)
    if init.any():
        first = np.clip(math.log(BETA) + ot + psi, min_logodds, max_logodds)
        rest = np.maximum(math.log(1.0 - BETA) + ot + phi, min_logodds)
        classes = out.classes.copy()
        logodds = out.logodds.copy()
        others = out.others.copy()
        classes[init] = EMPTY
        classes[init, 0] = cls[init]
        logodds[init] = 0.0
        logodds[init, 0] = first[init]
        others[init] = rest[init]
        out = MCBState(classes, logodds, others)
    return out


def mcb_miss(state: MCBState, *, phi: float = PHI, min_logodds: float = MIN_LOGODDS,
             empty_min_logodds: float | None = None) -> MCBState:
    """SSMI ``fuseObsFree``: every stored entry and others ``+= phi``, floored at
    ``min_logodds``. Voxels without classes floor at ``empty_min_logodds`` (SSMI uses the
    occupancy tree's clamping minimum there; default: ``min_logodds``)."""
    valid = state.valid
    lo = np.where(valid, np.maximum(state.logodds.astype(np.float64) + phi, min_logodds), 0.0)
    floor = np.where(valid.any(axis=1), min_logodds,
                     min_logodds if empty_min_logodds is None else empty_min_logodds)
    others = np.maximum(state.others.astype(np.float64) + phi, floor)
    return MCBState(state.classes, lo, others)


def mcb_observe(state: MCBState, cls: np.ndarray, *, psi: float = PSI, phi: float = PHI,
                max_logodds: float = MAX_LOGODDS, min_logodds: float = MIN_LOGODDS) -> MCBState:
    """Eq. 7 with eq. 9's occupied case for M voxels, one observation each: :func:`mcb_hit`
    with class ``cls[m]``; a voxel observed occupied without a class (``cls[m] < 0``: its points
    carried no class) takes the hit on ``others`` (``+= psi``, capped) and ``phi`` on its stored
    classes (floored)."""
    cls = np.asarray(cls).astype(np.int64)
    if cls.shape != (len(state),):
        raise ValueError(f"mcb_observe needs one class per voxel ({len(state)}), got {cls.shape}")
    known = cls >= 0
    out = mcb_hit(state, np.where(known, cls, 0), psi=psi, phi=phi, max_logodds=max_logodds,
                  min_logodds=min_logodds)
    if known.all():
        return out
    lo = state.logodds.astype(np.float64)
    blind_lo = np.where(state.valid, np.maximum(lo + phi, min_logodds), 0.0)
    blind_ot = np.minimum(state.others.astype(np.float64) + psi, max_logodds)
    return MCBState(np.where(known[:, None], out.classes, state.classes),
                    np.where(known[:, None], out.logodds, blind_lo),
                    np.where(known, out.others, blind_ot))


def mcb_occupancy(state: MCBState) -> np.ndarray:
    """Occupancy log-odds of eq. 5's vector: ``log(exp(others) + sum_i exp(l_i))`` (every
    class against free), ``float32`` (M,). Summed in a fixed order (largest term's shift, then
    slots 0, 1, 2 and others) so the compiled kernel repeats it exactly."""
    lo = state.logodds.astype(np.float64)
    ot = state.others.astype(np.float64)
    valid = state.valid
    top = ot.copy()
    for s in range(lo.shape[1]):
        top = np.where(valid[:, s] & (lo[:, s] > top), lo[:, s], top)
    acc = np.zeros(len(state))
    for s in range(lo.shape[1]):
        acc = acc + np.where(valid[:, s], np.exp(lo[:, s] - top), 0.0)
    acc = acc + np.exp(ot - top)
    return (np.log(acc) + top).astype(np.float32)


def mcb_probabilities(state: MCBState) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Eq. 6: softmax of (0 for free, stored classes, others).

    Returns:
        ``(p_classes (M, 3), p_others (M,), p_free (M,))``, float64; empty slots get 0.
    """
    lo = np.concatenate([np.zeros((len(state), 1)), state.logodds.astype(np.float64),
                         state.others.astype(np.float64)[:, None]], axis=1)
    mask = np.concatenate([np.ones((len(state), 1), bool), state.valid,
                           np.ones((len(state), 1), bool)], axis=1)
    norm = _logsumexp_masked(lo, mask, axis=1)
    p = np.where(mask, np.exp(lo - norm[:, None]), 0.0)
    return p[:, 1:1 + SLOTS], p[:, -1], p[:, 0]


PAIRINGS = ("printed", "ssmi")
"""How Algorithm 1 pairs a class held by one node only with a punished others (see the notes)."""


def _merge(g: MCBState, c: MCBState, punish_g: np.ndarray, punish_c: np.ndarray,
           max_logodds: float, min_logodds: float, pairing: str = "ssmi") -> MCBState:
    """Shared merge. A class held by one node only is averaged with a punished others: that of
    the node lacking it (``pairing="ssmi"``) or, as Algorithm 1 is printed, that of the node
    holding it (``"printed"``)."""
    if pairing not in PAIRINGS:
        raise ValueError(f"pairing must be one of {PAIRINGS}, got {pairing!r}")
    ga, ca = g.classes.astype(np.int64), c.classes.astype(np.int64)
    gl, cl = g.logodds.astype(np.float64), c.logodds.astype(np.float64)
    gv, cv = ga >= 0, ca >= 0
    match = _match(ga, gv, ca, cv)
    g_in_c = match.any(axis=2)
    c_in_g = match.any(axis=1)
    cl_for_g = np.where(match, cl[:, None, :], 0.0).sum(axis=2)
    delta_g = g.others.astype(np.float64) - punish_g
    delta_c = c.others.astype(np.float64) - punish_c
    own = pairing == "printed"
    g_alone = (delta_g if own else delta_c)[:, None]
    c_alone = (delta_c if own else delta_g)[:, None]
    val_g = np.where(g_in_c, (gl + cl_for_g) / 2.0, (gl + g_alone) / 2.0)
    val_c = (cl + c_alone) / 2.0
    cand_cls = np.concatenate([ga, ca], axis=1)
    cand_lo = np.concatenate([val_g, val_c], axis=1)
    cand_valid = np.concatenate([gv, cv & ~c_in_g], axis=1)
    _, order = _top(cand_lo, cand_valid, SLOTS)
    rest = np.zeros_like(cand_valid)
    np.put_along_axis(rest, order[:, SLOTS:], True, axis=1)
    rest &= cand_valid
    others = np.logaddexp((delta_g + delta_c) / 2.0, _logsumexp_masked(cand_lo, rest, axis=1))
    others = np.clip(others, min_logodds, max_logodds)
    return _state(cand_cls, np.clip(cand_lo, min_logodds, max_logodds), cand_valid, others)


def _union_size(g: MCBState, c: MCBState) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    gv, cv = g.valid, c.valid
    match = _match(g.classes, gv, c.classes, cv)
    n_g, n_c = gv.sum(axis=1), cv.sum(axis=1)
    n_z = n_g + (cv & ~match.any(axis=1)).sum(axis=1)
    return n_z, n_g, n_c


def merge_algorithm1(global_state: MCBState, local_state: MCBState, theta: float = THETA, *,
                     pairing: str = "printed", max_logodds: float = MAX_LOGODDS,
                     min_logodds: float = MIN_LOGODDS) -> MCBState:
    """EVSMaP Algorithm 1 for M node pairs (aligned states), in the reading given in the module
    notes: ``Delta = xi - theta log(1 + |Z|)``; a class held by one node only is averaged with
    a Delta (``pairing``: ``"printed"`` that node's own, ``"ssmi"`` the other node's); shared
    classes are averaged; top 3 kept; the rest folded with ``(Delta_G + Delta_C) / 2`` into
    others; everything clamped."""
    if len(global_state) != len(local_state):
        raise ValueError(f"merge_algorithm1: {len(global_state)} global voxels but "
                         f"{len(local_state)} local ones")
    n_z, _, _ = _union_size(global_state, local_state)
    punish = theta * np.log1p(n_z.astype(np.float64))
    return _merge(global_state, local_state, punish, punish, max_logodds, min_logodds, pairing)


def fold_algorithm1(children: MCBState, group: np.ndarray, n_groups: int,
                    theta: float = THETA, *, pairing: str = "printed") -> MCBState:
    """An inner node's state from its children's (Algorithm 1 "where two nodes merge"): the
    children of each group that hold classes are merged pairwise in child order,
    ``((c_0 + c_1) + c_2) + ...`` with :func:`merge_algorithm1`. Children without classes are
    skipped, as semantic_slam's inner-node fusion skips them; a group where no child has a class
    takes the child with the highest ``others`` (its occupancy log-odds: OctoMap's max).

    Args:
        children: the states of all children, grouped (``group`` ascending, child order within).
        group: (N,) the parent of each child, in ``[0, n_groups)``; every group has a child.
    """
    group = np.asarray(group, dtype=np.int64)
    has = children.has_semantics
    # fallback: the child with the highest others in each group (first on ties)
    order = np.lexsort((-children.others.astype(np.float64), group))
    first = np.r_[True, group[order][1:] != group[order][:-1]]
    out = children.take(order[first])
    classes, logodds, others = (out.classes.copy(), out.logodds.copy(), out.others.copy())
    idx = np.flatnonzero(has)
    if idx.size:
        g = group[idx]
        rank = np.arange(idx.size) - np.searchsorted(g, g, side="left")
        acc = children.take(idx[rank == 0])
        owner = g[rank == 0]
        slot = np.full(n_groups, -1, dtype=np.int64)
        slot[owner] = np.arange(owner.size)
        for r in range(1, int(rank.max()) + 1):
            at = rank == r
            pos = slot[g[at]]
            merged = merge_algorithm1(acc.take(pos), children.take(idx[at]), theta,
                                      pairing=pairing)
            acc.classes[pos] = merged.classes
            acc.logodds[pos] = merged.logodds
            acc.others[pos] = merged.others
        classes[owner], logodds[owner], others[owner] = acc.classes, acc.logodds, acc.others
    return MCBState(classes, logodds, others)


def merge_ssmi(a: MCBState, b: MCBState, *, max_logodds: float = MAX_LOGODDS,
               min_logodds: float = MIN_LOGODDS) -> MCBState:
    """SSMI ``semanticFusion``: a class absent from a node takes that node's
    ``others - log(#classes it misses + 1)``; averages; top 3; the rest folded; clamped."""
    if len(a) != len(b):
        raise ValueError(f"merge_ssmi: {len(a)} and {len(b)} voxels")
    n_z, n_a, n_b = _union_size(a, b)
    return _merge(a, b, np.log1p((n_z - n_a).astype(np.float64)),
                  np.log1p((n_z - n_b).astype(np.float64)), max_logodds, min_logodds)


_DENSE_LIMIT = 1 << 24
"""Largest voxels x classes table :func:`build_local` sums densely."""


def build_local(voxel_index: np.ndarray, classes: np.ndarray, probs: np.ndarray, n_voxels: int,
                *, hit: float = PSI, max_logodds: float = MAX_LOGODDS,
                min_logodds: float = MIN_LOGODDS) -> MCBState:
    """One local-map node per voxel from a frame's per-point top-k observations.

    Args:
        voxel_index: integer (P,) voxel of each point, in [0, n_voxels).
        classes: integer (P, k) top-k classes per point (-1 entries are ignored; their mass
            counts as others).
        probs: (P, k) their probabilities (sum <= 1 per point).
        n_voxels: number of voxels in the local map.
        hit: occupancy log-odds of an observed voxel (default psi).

    Returns:
        :class:`MCBState` of ``n_voxels``: for a voxel with points, the top 3 classes of the mean
        distribution ``pbar`` with ``l_c = hit + log(pbar_c)`` and ``others = hit +
        log(1 - sum of the 3 kept)`` (probabilities floored at 1e-4, log-odds clamped); voxels
        without points are empty with others 0 (unknown). Ties in ``pbar`` go to the smaller
        class id.
    """
    vi = np.asarray(voxel_index).astype(np.int64).ravel()
    cl = np.asarray(classes).astype(np.int64)
    pr = np.asarray(probs, dtype=np.float64)
    if cl.ndim != 2 or pr.shape != cl.shape or cl.shape[0] != vi.shape[0]:
        raise ValueError(f"build_local needs voxel_index (P,), classes (P, k) and probs (P, k); "
                         f"got {vi.shape}, {cl.shape}, {pr.shape}")
    if vi.size and (vi.min() < 0 or vi.max() >= n_voxels):
        raise ValueError(f"build_local: voxel indices must lie in [0, {n_voxels})")
    out_cls = np.full((n_voxels, SLOTS), EMPTY, np.int64)
    out_p = np.zeros((n_voxels, SLOTS))
    counts = np.bincount(vi, minlength=n_voxels)
    k = cl.shape[1]
    span = int(cl.max()) + 1 if cl.size else 0
    if span > 0 and n_voxels * span <= _DENSE_LIMIT:
        # dense (voxel, class) sums, one slot at a time: no sort, O(points) - the common case
        # (tens of classes); entries with class -1 or probability 0 add nothing
        sums = np.zeros(n_voxels * span)
        base = vi * span
        for j in range(k):
            c, w = cl[:, j], pr[:, j]
            ok = (c >= 0) & (w > 0)
            if not ok.all():
                c, w = np.where(ok, c, 0), np.where(ok, w, 0.0)
            sums += np.bincount(base + c, weights=w, minlength=n_voxels * span)
        sums = sums.reshape(n_voxels, span)
        mean = sums / np.maximum(counts, 1)[:, None]
        order = np.argsort(-mean, axis=1, kind="stable")[:, :SLOTS]  # ties: smaller class id
        top = np.take_along_axis(mean, order, axis=1)
        width = order.shape[1]
        out_cls[:, :width] = np.where(top > 0, order, EMPTY)
        out_p[:, :width] = np.where(top > 0, top, 0.0)
    elif span > 0:
        flat_v = np.repeat(vi, k)
        flat_c = cl.ravel()
        flat_p = pr.ravel()
        keep = (flat_c >= 0) & (flat_p > 0)
        flat_v, flat_c, flat_p = flat_v[keep], flat_c[keep], flat_p[keep]
        key, inverse = np.unique(flat_v * span + flat_c, return_inverse=True)
        mean = np.bincount(inverse.ravel(), weights=flat_p) / counts[key // span]
        kv, kc = key // span, key % span
        order = np.lexsort((kc, -mean, kv))
        kv, kc, mean = kv[order], kc[order], mean[order]
        rank = np.arange(kv.size) - np.searchsorted(kv, kv, side="left")
        top = rank < SLOTS
        out_cls[kv[top], rank[top]] = kc[top]
        out_p[kv[top], rank[top]] = mean[top]
    observed = counts > 0
    valid = out_cls >= 0
    rest = np.maximum(1.0 - out_p.sum(axis=1), PROB_MIN)
    with np.errstate(divide="ignore"):
        lo = hit + np.log(np.maximum(out_p, PROB_MIN))
    lo = np.where(valid, np.clip(lo, min_logodds, max_logodds), 0.0)
    others = np.where(observed, np.clip(hit + np.log(rest), min_logodds, max_logodds), 0.0)
    return MCBState(out_cls, lo, others)


__all__ = [
    "ALPHA", "BETA", "EMPTY", "EPSILON", "MAX_LOGODDS", "MIN_LOGODDS", "PHI", "PSI", "SLOTS",
    "THETA", "MCBState", "average_color", "average_node_color", "build_local", "color_is_set",
    "PAIRINGS", "fold_algorithm1", "fuse_bayes", "fuse_max", "integrate_color", "mcb_hit",
    "mcb_miss", "mcb_observe", "mcb_occupancy", "mcb_probabilities", "merge_algorithm1",
    "merge_ssmi",
]
