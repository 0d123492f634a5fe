"""Per-pixel top-k classes and softmax probabilities of a segmentation network's logits.

The straightforward way - classes last, a softmax over every class, then ``topk`` - spends most
of a CPU frame moving data: a (C, H, W) -> (H, W, C) copy, C exponentials written per pixel,
and ``topk`` along rows of a few tens of elements. :func:`top_k` instead

* sweeps the logits channel by channel (contiguous rows of the NCHW output) keeping the k
  largest per pixel (a compiled kernel; ties go to the smaller class id),
* takes the softmax denominator ``sum_c exp(l_c - max)`` a few channels at a time (vectorised
  exponentials, shifted by the per-pixel max from the sweep, no (H, W, C) copy), and
* computes only the k probabilities kept: ``p = exp(l - max) / denominator``, the softmax
  itself.

Labels are those of the softmax (softmax is monotonic in the logits); probabilities agree with
``torch.softmax`` to a few float32 ulps (``tests/segmenters/test_topk.py``).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import torch


def _numba_njit() -> Callable[..., Any] | None:
    """numba's ``njit``, or None where numba cannot be imported."""
    try:
        from numba import njit
    except ImportError:  # pragma: no cover
        return None
    return njit


njit = _numba_njit()


def _sweep(x, k):
    """The ``k`` largest values per column of float32 ``x`` (C, N), largest first, and their
    row indices (ties: the smaller index first): ``(values (k, N), classes (k, N) int16)``."""
    c_count, n = x.shape
    vals = np.full((k, n), -np.inf, np.float32)
    cls = np.zeros((k, n), np.int16)
    last = k - 1
    for c in range(c_count):
        row = x[c]
        for p in range(n):
            v = row[p]
            if v > vals[last, p]:
                j = last
                while j > 0 and v > vals[j - 1, p]:
                    vals[j, p] = vals[j - 1, p]
                    cls[j, p] = cls[j - 1, p]
                    j -= 1
                vals[j, p] = v
                cls[j, p] = c
    return vals, cls


def _sweep3(x):
    """:func:`_sweep` for ``k <= 3`` with one array per slot (the compiler keeps the common
    case - a value below the third - to one compare per element): 4x faster."""
    c_count, n = x.shape
    v0 = np.full(n, -np.inf, np.float32)
    v1 = v0.copy()
    v2 = v0.copy()
    c0 = np.zeros(n, np.int16)
    c1 = c0.copy()
    c2 = c0.copy()
    for c in range(c_count):
        row = x[c]
        for p in range(n):
            v = row[p]
            if v > v2[p]:
                if v > v1[p]:
                    v2[p] = v1[p]
                    c2[p] = c1[p]
                    if v > v0[p]:
                        v1[p] = v0[p]
                        c1[p] = c0[p]
                        v0[p] = v
                        c0[p] = c
                    else:
                        v1[p] = v
                        c1[p] = c
                else:
                    v2[p] = v
                    c2[p] = c
    vals = np.empty((3, n), np.float32)
    cls = np.empty((3, n), np.int16)
    vals[0], vals[1], vals[2] = v0, v1, v2
    cls[0], cls[1], cls[2] = c0, c1, c2
    return vals, cls


def _probabilities(vals, total):
    """``exp(v - max) / sum_c exp(l_c - max)`` of the kept values (``vals[0]`` is the max)."""
    k, n = vals.shape
    out = np.empty((n, k), np.float32)
    for p in range(n):
        for j in range(k):
            out[p, j] = np.float32(np.exp(np.float64(vals[j, p]) - np.float64(vals[0, p]))
                                   / np.float64(total[p]))
    return out


CHUNK = 8
"""Channels exponentiated at a time for the softmax denominator (bounds the temporary)."""


def _denominator(flat: torch.Tensor, top: torch.Tensor) -> torch.Tensor:
    """``sum_c exp(l_c - max)`` per pixel, shifted by the max so that large logits lose no
    precision, a few channels at a time (vectorised exp, no (C, N) temporary). One chunk buffer
    is reused in place: allocating a fresh 8 x N temporary per operation and chunk (the kernel
    zero-fills every new page) cost three times the arithmetic."""
    c_count, n = flat.shape
    total = torch.zeros(n, dtype=torch.float32)
    buf = torch.empty((min(CHUNK, c_count), n), dtype=torch.float32)
    for start in range(0, c_count, CHUNK):
        chunk = buf[:min(CHUNK, c_count - start)]
        torch.sub(flat[start:start + CHUNK], top, out=chunk)
        chunk.exp_()
        total += chunk.sum(0)
    return total


if njit is not None:
    _sweep = njit(cache=True, nogil=True)(_sweep)
    _sweep3 = njit(cache=True, nogil=True)(_sweep3)
    _probabilities = njit(cache=True, nogil=True)(_probabilities)


def top_k_softmax(logits: torch.Tensor, k: int) -> tuple[np.ndarray, np.ndarray]:
    """The top-``k`` classes (int16) and softmax probabilities (float32, in [0, 1]) of
    ``logits`` (C, H, W), each (H, W, k), most likely first."""
    x = logits.detach().float().contiguous()
    c_count, h, w = x.shape
    if njit is None:  # the reference: classes last, softmax, topk
        top_p, top_c = torch.softmax(x.permute(1, 2, 0), dim=-1).topk(k, dim=-1)
        return (top_c.to(torch.int16).numpy(),
                np.clip(top_p.numpy(), 0.0, 1.0).astype(np.float32))
    flat = x.reshape(c_count, h * w)
    if k <= 3:
        vals, cls = _sweep3(flat.numpy())
        vals, cls = vals[:k], cls[:k]
    else:
        vals, cls = _sweep(flat.numpy(), k)
    total = _denominator(flat, torch.from_numpy(vals[0]))
    probs = np.clip(_probabilities(vals, total.numpy()), 0.0, 1.0)
    return np.ascontiguousarray(cls.T).reshape(h, w, k), probs.reshape(h, w, k)
