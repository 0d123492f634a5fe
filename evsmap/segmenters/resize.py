"""Bilinear resizing whose result does not depend on the thread count, the pipeline or the
machine's core count.

torch's CPU bilinear kernel (``F.interpolate(mode="bilinear")``) rounds differently with one
intra-op thread than with two or more: measured on torch 2.13's AVX-512 kernels, a 640x480 RGB
frame resized to 320x240 differs by up to 1 float32 ulp (6e-8 after the division by 255) between
``torch.set_num_threads(1)`` and 2, on a channels-last (HWC-strided) tensor and on a contiguous
NCHW one alike; 3, 4 and 8 threads agree with 2 there, but nothing promises it. The network's
inputs and the observation's resize from the network's input size to the frame's are therefore
computed here: one fixed per-pixel formula in float32, every multiply and add rounded on its
own (numba compiles without ``fastmath``, so without fused multiply-adds; the numpy fallback
rounds each operation too, and both give the same bits, ``tests/segmenters/test_resize.py``),
one pixel at a time on the calling thread.

The formula is torch's (``upsample_bilinear2d``): along each axis the source position of output
index ``i`` is ``scale * (i + 0.5) - 0.5`` clamped at 0 with ``scale = float32(n_in / n_out)``
(``align_corners=False``) or ``float32((n_in - 1) / (n_out - 1)) * i`` (``align_corners=True``);
lower index ``floor``, upper ``lower + 1`` within the image, weights ``1 - l`` and ``l``; a
pixel is ``(row0[x0] * wx0 + row0[x1] * wx1) * wy0 + (row1[x0] * wx0 + row1[x1] * wx1) * wy1``.
It agrees with torch to a few float32 ulps (torch may fuse the multiply-adds).
"""

from __future__ import annotations

import numpy as np

from evsmap.segmenters.topk import njit


def source_axis(n_in: int, n_out: int, *, align_corners: bool
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(lower, upper, weight of lower, weight of upper)`` for each of ``n_out`` output
    positions along an axis of ``n_in`` input positions, in float32 as torch computes them."""
    dst = np.arange(n_out, dtype=np.float32)
    if align_corners:
        scale = np.float32((n_in - 1) / (n_out - 1)) if n_out > 1 else np.float32(0)
        src = scale * dst
    else:
        scale = np.float32(n_in) / np.float32(n_out)
        src = np.maximum(scale * (dst + np.float32(0.5)) - np.float32(0.5), np.float32(0))
    lower = np.minimum(np.floor(src).astype(np.int64), n_in - 1)
    upper = np.minimum(lower + 1, n_in - 1)
    w1 = np.clip(src - lower.astype(np.float32), np.float32(0), np.float32(1))
    return lower, upper, (np.float32(1) - w1).astype(np.float32), w1.astype(np.float32)


def _bilinear_kernel(x, y0, y1, wy0, wy1, x0, x1, wx0, wx1, out):
    """``out`` (C, H, W) from ``x`` (C, h, w), float32, one output pixel at a time."""
    for c in range(x.shape[0]):
        for i in range(out.shape[1]):
            top = x[c, y0[i]]
            bottom = x[c, y1[i]]
            a, b = wy0[i], wy1[i]
            row = out[c, i]
            for j in range(out.shape[2]):
                upper = top[x0[j]] * wx0[j] + top[x1[j]] * wx1[j]
                lower = bottom[x0[j]] * wx0[j] + bottom[x1[j]] * wx1[j]
                row[j] = upper * a + lower * b


def _bilinear_numpy(x, y0, y1, wy0, wy1, x0, x1, wx0, wx1, out):
    """:func:`_bilinear_kernel` with whole-array numpy operations (each rounded on its own)."""
    def along_x(rows: np.ndarray) -> np.ndarray:
        return rows[:, :, x0] * wx0 + rows[:, :, x1] * wx1

    out[...] = along_x(x[:, y0]) * wy0[:, None] + along_x(x[:, y1]) * wy1[:, None]


_compiled = njit(cache=True, nogil=True)(_bilinear_kernel) if njit is not None else None


def bilinear(x: np.ndarray, size: tuple[int, int], *, align_corners: bool = False,
             compiled: bool = True) -> np.ndarray:
    """``x`` (C, h, w) resized bilinearly to ``size`` (H, W): float32 (C, H, W), the same bits
    whatever the thread count (see the module notes). ``compiled=False`` runs the numpy
    formula (also what runs where numba is missing)."""
    x = np.ascontiguousarray(x, dtype=np.float32)
    if x.ndim != 3:
        raise ValueError(f"bilinear needs a (C, h, w) array, got shape {x.shape}")
    height, width = (int(v) for v in size)
    if height < 1 or width < 1:
        raise ValueError(f"bilinear: the output size must be positive, got {size}")
    out = np.empty((x.shape[0], height, width), np.float32)
    args = (*source_axis(x.shape[1], height, align_corners=align_corners),
            *source_axis(x.shape[2], width, align_corners=align_corners))
    kernel = _compiled if compiled and _compiled is not None else _bilinear_numpy
    kernel(x, *args, out)
    return out
