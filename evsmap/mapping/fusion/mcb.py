"""Multi-class Bayesian node state and its per-observation rules (EVSMaP eqs. 5-9, SSMI
``SemanticsLogOdds``), vectorised over M voxels.

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
* :func:`~evsmap.mapping.fusion.merge.merge_ssmi` - SSMI's ``semanticFusion`` of two nodes: a
  class absent from one node takes that node's ``others - log(#classes it misses + 1)``; values
  averaged; others averaged; top 3 kept, the rest folded into others (log-sum-exp); here also
  clamped.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from evsmap.mapping.fusion.slots import EMPTY, SLOTS, logsumexp_masked, pad_slots, top_slots

ALPHA = 0.8
"""Bayesian (semantic_slam) and SSMI: share of the residual given to a newly seen class."""


BETA = 0.1
"""SSMI ``initSemantics``: share given to the first class of a voxel without classes."""

PSI = 1.0
"""SSMI: log-odds added to the observed class on a hit."""

PHI = -0.1
"""SSMI: log-odds added to every other entry on a hit and to every entry on a miss."""


PROB_MIN, PROB_MAX = 1e-4, 0.9999
"""SSMI clamping probabilities."""

MIN_LOGODDS = math.log(PROB_MIN / (1.0 - PROB_MIN))
"""-9.21"""

MAX_LOGODDS = math.log(PROB_MAX / (1.0 - PROB_MAX))
"""+9.21"""


CLASS_ID = np.int32
"""The dtype of :attr:`MCBState.classes`."""


def _class_ids(c: np.ndarray) -> np.ndarray:
    """``c`` as :data:`CLASS_ID`; an id outside its range is an error (a narrowing cast would
    wrap it onto another class without a word)."""
    if not np.issubdtype(c.dtype, np.integer):
        raise ValueError(f"MCBState class ids must be integers, got {c.dtype}")
    if c.size and np.dtype(c.dtype).itemsize > np.dtype(CLASS_ID).itemsize:
        info = np.iinfo(CLASS_ID)
        if int(c.min()) < EMPTY or int(c.max()) > info.max:
            raise ValueError(f"MCBState class ids must lie in [{EMPTY}, {info.max}]; got "
                             f"[{int(c.min())}, {int(c.max())}]")
    return c.astype(CLASS_ID, copy=False)


@dataclass(frozen=True, eq=False)
class MCBState:
    """Multi-class Bayesian semantics of M voxels (struct of arrays).

    Attributes:
        classes: ``int32`` (M, 3) class ids, most likely first, -1 in empty slots (which come
            last). Ids are not only a label set's classes: the generator front end numbers the
            distinct class colours of a tree level (tens of thousands, averaged colours
            included), so ids are kept in 32 bits and a wider id is refused, never wrapped.
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
        object.__setattr__(self, "classes", _class_ids(c))
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
        has: npt.NDArray[np.bool_] = np.any(self.valid, axis=1)
        return has

    @classmethod
    def empty(cls, m: int, others: float = 0.0) -> MCBState:
        """M voxels without classes whose occupancy log-odds is ``others`` (0 = unknown)."""
        return cls(np.full((m, SLOTS), EMPTY, CLASS_ID), np.zeros((m, SLOTS), np.float32),
                   np.full(m, others, np.float32))

    def take(self, index: np.ndarray) -> MCBState:
        """The voxels at ``index`` (any numpy index)."""
        return MCBState(self.classes[index], self.logodds[index], self.others[index])

    def equals(self, other: MCBState) -> np.ndarray:
        """(M,) bool: exactly equal classes, log-odds and others (pruning test)."""
        same: npt.NDArray[np.bool_] = (np.all(self.classes == other.classes, axis=1)
                                       & np.all(self.logodds == other.logodds, axis=1)
                                       & (self.others == other.others))
        return same


def state_from_candidates(cls: np.ndarray, lo: np.ndarray, valid: np.ndarray,
                          others: np.ndarray) -> MCBState:
    """Sort candidates (M, K) most likely first, keep 3, normalise empty slots."""
    idx, _ = top_slots(lo, valid, SLOTS)
    v = np.take_along_axis(valid, idx, axis=1)
    c = np.where(v, np.take_along_axis(cls, idx, axis=1), EMPTY)
    lo = np.where(v, np.take_along_axis(lo, idx, axis=1), 0.0)
    return MCBState(pad_slots(c, SLOTS, EMPTY), pad_slots(lo, SLOTS, 0.0), others)



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
    _, order = top_slots(cand_lo, cand_valid, SLOTS)
    # Fold the 4th entry (only when 3 classes were stored and a new one entered).
    fourth = order[:, SLOTS]
    fold = np.take_along_axis(cand_valid, fourth[:, None], axis=1)[:, 0]
    fold_lo = np.take_along_axis(cand_lo, fourth[:, None], axis=1)[:, 0]
    others_new = np.where(fold, np.logaddexp(others_new, fold_lo), others_new)
    others_new = np.clip(others_new, min_logodds, max_logodds)
    out = state_from_candidates(cand_cls, cand_lo, cand_valid, others_new)

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
    norm = logsumexp_masked(lo, mask, axis=1)
    p = np.where(mask, np.exp(lo - norm[:, None]), 0.0)
    return p[:, 1:1 + SLOTS], p[:, -1], p[:, 0]

