"""The local map of one frame: one multi-class Bayesian node per voxel from the frame's
per-point top-k observations.

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

import numpy as np
import numpy.typing as npt

from evsmap.mapping.fusion.mcb import MAX_LOGODDS, MIN_LOGODDS, PROB_MIN, PSI, MCBState
from evsmap.mapping.fusion.slots import EMPTY, SLOTS

DENSE_LIMIT = 1 << 24
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
    if span > 0 and n_voxels * span <= DENSE_LIMIT:
        # dense (voxel, class) sums, one slot at a time: no sort, O(points) - the common case
        # (tens of classes); entries with class -1 or probability 0 add nothing
        sums: npt.NDArray[np.float64] = np.zeros(n_voxels * span)
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


