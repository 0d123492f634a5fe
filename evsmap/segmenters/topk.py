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
    zero-fills every new page) cost three times the arithmetic. torch's exponential and sum split
    the pixels (never the channels of one pixel) across its intra-op threads: the same bits at
    1, 2 and 4 threads (measured on torch 2.13's AVX-512 kernels, and held by
    ``tests/segmenters/test_thread_independence.py``), where its bilinear resize was not."""
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


# ------------------------------------------------------------ upsampling fused with the top-k
BLOCK = 8192
"""Output pixels per block of :func:`top_k_upsampled` (their 40 logits stay in the L2 cache)."""


def _source_axis(n_in: int, n_out: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bilinear source positions along one axis with ``align_corners=True`` (what the
    networks' final resize does, :func:`evsmap.models.layers.resize_to`), in torch's float32
    arithmetic: ``src = float32((n_in - 1) / (n_out - 1)) * dst``; ``(lower, upper, weight of
    upper)`` per output position."""
    scale = np.float32((n_in - 1) / (n_out - 1)) if n_out > 1 else np.float32(0)
    src = scale * np.arange(n_out, dtype=np.float32)
    lower = np.minimum(np.floor(src).astype(np.int64), n_in - 1)
    upper = np.minimum(lower + 1, n_in - 1)
    return lower, upper, (src - lower.astype(np.float32)).astype(np.float32)


def _upsample(low, pixels, width, y0, y1, wy, x0, x1, wx, buf, scratch):
    """Bilinear logits of the output ``pixels`` (sorted flat indices in an image ``width``
    wide) from ``low`` (C, h, w), channel by channel into ``buf`` (C, m), in torch's order of
    operations: ``hy * (hx * low[a, c] + lx * low[a, d]) + ly * (hx * low[b, c] + lx * low[b,
    d])``. The source rows the block spans are interpolated along x once (the two inner
    terms) into ``scratch`` (at least (rows spanned, C, width)), then each output row combines
    two of them."""
    m = pixels.shape[0]
    c_count = low.shape[0]
    one = np.float32(1)
    rows = pixels // width
    cols = pixels - rows * width
    first = y0[rows[0]]
    span = y1[rows[m - 1]] - first + 1
    along_x = scratch[:span]
    for s in range(span):
        for ch in range(c_count):
            src = low[ch, first + s]
            dst = along_x[s, ch]
            for q in range(width):
                dst[q] = (one - wx[q]) * src[x0[q]] + wx[q] * src[x1[q]]
    starts = [0]
    for j in range(1, m):
        if rows[j] != rows[j - 1]:
            starts.append(j)
    starts.append(m)
    for s in range(len(starts) - 1):
        lo, hi = starts[s], starts[s + 1]
        r = rows[lo]
        ly = wy[r]
        hy = one - ly
        c0 = cols[lo]
        run = cols[hi - 1] - c0 == hi - 1 - lo  # consecutive columns: no gather, vectorised
        for ch in range(c_count):
            top = along_x[y0[r] - first, ch]
            bottom = along_x[y1[r] - first, ch]
            out = buf[ch]
            if run:  # slices first: indices from 0 vectorise (no wraparound test)
                o, a, b = out[lo:hi], top[c0:c0 + hi - lo], bottom[c0:c0 + hi - lo]
                for j in range(hi - lo):
                    o[j] = hy * a[j] + ly * b[j]
            else:
                for j in range(lo, hi):
                    out[j] = hy * top[cols[j]] + ly * bottom[cols[j]]


def _scatter(vals, cls, total, pixels, k, out_cls, out_p):
    """The kept classes and softmax probabilities of a block written at their ``pixels``."""
    for j in range(pixels.shape[0]):
        p = pixels[j]
        denominator = np.float64(total[j])
        for i in range(k):
            out_cls[p, i] = cls[i, j]
            # the top value's exp(0) is 1 exactly: one exponential fewer a pixel
            e = 1.0 if i == 0 else np.exp(np.float64(vals[i, j]) - np.float64(vals[0, j]))
            prob = np.float32(e / denominator)
            out_p[p, i] = min(max(prob, np.float32(0)), np.float32(1))


if njit is not None:
    _upsample = njit(cache=True, nogil=True)(_upsample)
    _scatter = njit(cache=True, nogil=True)(_scatter)


def top_k_upsampled(low: torch.Tensor, size: tuple[int, int], k: int,
                    pixels: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """:func:`top_k_softmax` of ``low`` (C, h, w) resized bilinearly (``align_corners=True``)
    to ``size`` (H, W), without the (C, H, W) logits: each block of output pixels is
    interpolated, swept for its top 3 and exponentiated while it sits in the cache.

    The same arithmetic as the network's own resize followed by :func:`top_k_softmax` up to
    float32 rounding (the same labels; ``tests/segmenters/test_topk.py``). Only ``pixels``
    (sorted flat indices into H x W; None: all) are computed; the others hold class 0 with
    probability 0. ``k`` must be 1 to 3 and the compiler present (callers fall back to
    resizing then :func:`top_k_softmax`).
    """
    if njit is None or not 1 <= k <= 3:
        raise ValueError("top_k_upsampled needs numba and k <= 3")
    x = low.detach().float().contiguous().numpy()
    c_count, h, w = x.shape
    height, width = size
    y0, y1, wy = _source_axis(h, height)
    x0, x1, wx = _source_axis(w, width)
    if pixels is None:
        pixels = np.arange(height * width, dtype=np.int64)
    pixels = np.ascontiguousarray(pixels, dtype=np.int64)
    if pixels.size and (pixels.min() < 0 or pixels.max() >= height * width):
        raise ValueError(f"pixels must index a {height}x{width} image")
    out_cls = np.zeros((height * width, k), np.int16)
    out_p = np.zeros((height * width, k), np.float32)
    starts = np.arange(0, len(pixels), BLOCK)
    firsts = y0[pixels[starts] // width] if len(pixels) else np.zeros(0, np.int64)
    lasts = y1[pixels[np.minimum(starts + BLOCK, len(pixels)) - 1] // width] \
        if len(pixels) else np.zeros(0, np.int64)
    span = int((lasts - firsts).max()) + 1 if len(pixels) else 0
    scratch = np.empty((span, c_count, width), np.float32)  # reused: no page faults a block
    store = np.empty(c_count * _padded(min(BLOCK, len(pixels))), np.float32)
    top = np.zeros(_padded(min(BLOCK, len(pixels))), np.float32)
    total = np.empty_like(top)
    for start in range(0, len(pixels), BLOCK):
        block = pixels[start:start + BLOCK]
        m, padded = len(block), _padded(len(block))
        buf = store[:c_count * padded].reshape(c_count, padded)
        buf[:, m:] = 0
        _upsample(x, block, width, y0, y1, wy, x0, x1, wx, buf, scratch)
        vals, cls = _sweep3(buf[:, :m])
        top[:m] = vals[0]
        # numpy's vectorised float32 exponential, on this thread (torch's intra-op pool woken
        # for every block cost more than the arithmetic next to a spinning ONNX Runtime)
        np.subtract(buf, top[:padded], out=buf)
        np.exp(buf, out=buf)
        np.sum(buf, axis=0, out=total[:padded])
        _scatter(vals, cls, total[:m], block, k, out_cls, out_p)
    return out_cls.reshape(height, width, k), out_p.reshape(height, width, k)


def _padded(m: int) -> int:
    """``m`` columns rounded up to whole vectors: every column of a block then goes through the
    vectorised exponential and sum (none through a scalar tail), so a pixel's probabilities do
    not depend on which block it fell in or on the pixels asked for."""
    return -(-m // PAD) * PAD


PAD = 64


def nearest_observation(classes: np.ndarray, probs: np.ndarray, size: tuple[int, int]
                        ) -> tuple[np.ndarray, np.ndarray]:
    """A top-k observation (h, w, k) at ``size`` (H, W) by nearest neighbour: output pixel
    (y, x) takes input pixel ``(floor((y + 0.5) h / H), floor((x + 0.5) w / W))``, the input
    pixel whose footprint holds the output pixel's centre."""
    h, w = classes.shape[:2]
    height, width = size
    rows = np.minimum(((np.arange(height) + 0.5) * h / height).astype(np.int64), h - 1)
    cols = np.minimum(((np.arange(width) + 0.5) * w / width).astype(np.int64), w - 1)
    return classes[rows[:, None], cols[None, :]], probs[rows[:, None], cols[None, :]]
