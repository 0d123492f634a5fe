"""The semantic slots every fusion rule works on, vectorised over M voxels.

A voxel holds up to :data:`SLOTS` (3) classes, most likely first; an empty slot holds class
:data:`EMPTY` (-1). These helpers match, rank and pad slot arrays for the colour-free rule
sets (:mod:`~evsmap.mapping.fusion.mcb`, :mod:`~evsmap.mapping.fusion.merge` and
semantic_slam's rules in ``baselines``).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

EMPTY = -1
"""Class id of an empty semantic slot."""

SLOTS = 3
"""Semantic slots per voxel (semantic_slam's NUM_SEMANTICS, SSMI's 3 classes + others)."""


def match_slots(a: np.ndarray, av: np.ndarray, b: np.ndarray, bv: np.ndarray) -> np.ndarray:
    """(M, na, nb) bool: slot i of a holds the same (valid) class as slot j of b."""
    same: npt.NDArray[np.bool_] = ((a[:, :, None] == b[:, None, :])
                                   & av[:, :, None] & bv[:, None, :])
    return same


def top_slots(values: np.ndarray, valid: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Indices (M, n) of the n largest valid values, stable (earlier candidate first on ties),
    and the rank order of all candidates (M, K)."""
    key = np.where(valid, -values, np.inf)
    order = np.argsort(key, axis=1, kind="stable")
    return order[:, :n], order



def pad_slots(x: np.ndarray, n: int, fill: float) -> np.ndarray:
    """First n columns of x, padded with ``fill`` when x has fewer."""
    if x.shape[1] >= n:
        return x[:, :n]
    pad = np.full((x.shape[0], n - x.shape[1]), fill, dtype=x.dtype)
    return np.concatenate([x, pad], axis=1)



def logsumexp_masked(values: np.ndarray, mask: np.ndarray, axis: int) -> np.ndarray:
    """log(sum(exp(values[mask]))) along ``axis``; -inf where nothing is masked."""
    v = np.where(mask, values, -np.inf)
    top = np.max(v, axis=axis, keepdims=True)
    safe = np.where(np.isfinite(top), top, 0.0)
    with np.errstate(divide="ignore"):
        out = np.log(np.sum(np.exp(v - safe), axis=axis, keepdims=True)) + safe
    total: npt.NDArray[np.floating[Any]] = np.squeeze(out, axis=axis)
    return total

