"""Merging two multi-class Bayesian nodes: EVSMaP's Algorithm 1 (and SSMI's
``semanticFusion``), vectorised over M node pairs, and the inner-node fold built on it.

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
"""

from __future__ import annotations

import numpy as np

from evsmap.mapping.fusion.mcb import MAX_LOGODDS, MIN_LOGODDS, MCBState, state_from_candidates
from evsmap.mapping.fusion.slots import SLOTS, logsumexp_masked, match_slots, top_slots

THETA = 0.6
"""EVSMaP Algorithm 1 punishment value."""


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
    match = match_slots(ga, gv, ca, cv)
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
    _, order = top_slots(cand_lo, cand_valid, SLOTS)
    rest = np.zeros_like(cand_valid)
    np.put_along_axis(rest, order[:, SLOTS:], True, axis=1)
    rest &= cand_valid
    others = np.logaddexp((delta_g + delta_c) / 2.0, logsumexp_masked(cand_lo, rest, axis=1))
    others = np.clip(others, min_logodds, max_logodds)
    return state_from_candidates(cand_cls, np.clip(cand_lo, min_logodds, max_logodds),
                                 cand_valid, others)


def _union_size(g: MCBState, c: MCBState) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    gv, cv = g.valid, c.valid
    match = match_slots(g.classes, gv, c.classes, cv)
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


