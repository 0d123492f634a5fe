"""The synthetic renderer's per-pixel colour (albedo x procedural texture x shading) as one
compiled pass.

:meth:`evsmap.synth.render.RoomRenderer.render` computed it with whole-image numpy operations:
about 20 full-frame float64 temporaries and nine hash evaluations per pixel, over 100 ms of a
640x480 frame on one core, most of a synthetic frame's "read" time. :func:`linear_colour` does
the same arithmetic per pixel in one loop, operation for operation in the numpy order (float64,
no fused multiply-add, the same integer hash with uint64 wrap-around), so the image is the same
bit for bit (``tests/synth/test_shading.py`` compares it with the numpy reference,
:func:`linear_colour_numpy`). The gamma curve and the sensor noise stay in numpy (numpy's
vectorised ``power`` rounds differently from libm's in the last bit).

The kernel releases the GIL, so a reader thread renders the next frame while other threads
segment and integrate (``evsmap map --pipeline``).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np


def _numba_njit() -> Callable[..., Any] | None:
    """numba's ``njit``, or None where numba cannot be imported."""
    try:
        from numba import njit
    except ImportError:  # pragma: no cover - numba is a dependency
        return None
    return njit


njit = _numba_njit()

COARSE_CELL = 0.15
"""Lattice of the coarse value noise, metres."""

FINE_CELL = 0.01
"""Lattice of the fine grain, metres."""

AMBIENT = 0.35
"""Shading's ambient term."""

_KEY_BIAS = 1 << 20
"""Added to lattice coordinates so that the hash sees non-negative integers."""


# ----------------------------------------------------------------------- numpy reference
def hash01(ix: np.ndarray, iy: np.ndarray, iz: np.ndarray, seed: np.ndarray) -> np.ndarray:
    """Deterministic pseudo-random value in [0, 1) per integer lattice point and seed."""
    h = (ix.astype(np.uint64) * np.uint64(73856093)) ^ (iy.astype(np.uint64) * np.uint64(19349663))
    h ^= iz.astype(np.uint64) * np.uint64(83492791)
    h ^= seed.astype(np.uint64) * np.uint64(2654435761)
    h ^= h >> np.uint64(13)
    h *= np.uint64(0x5BD1E995)
    h ^= h >> np.uint64(15)
    return (h & np.uint64(0xFFFFFF)).astype(np.float64) / float(0x1000000)


def value_noise(pts: np.ndarray, cell: float, seed: np.ndarray) -> np.ndarray:
    """Trilinear value noise on a world-fixed lattice of ``cell`` metres (view-consistent)."""
    g = pts / cell
    base = np.floor(g)
    f = g - base
    f = f * f * (3 - 2 * f)
    b = base.astype(np.int64) + _KEY_BIAS
    out = np.zeros(pts.shape[:-1])
    for dx in (0, 1):
        wx = f[..., 0] if dx else 1 - f[..., 0]
        for dy in (0, 1):
            wy = f[..., 1] if dy else 1 - f[..., 1]
            for dz in (0, 1):
                wz = f[..., 2] if dz else 1 - f[..., 2]
                out += wx * wy * wz * hash01(b[..., 0] + dx, b[..., 1] + dy, b[..., 2] + dz, seed)
    return out


def texture(pts: np.ndarray, part: np.ndarray) -> np.ndarray:
    """Brightness multiplier around 1: coarse blotches plus fine grain, per instance."""
    seed = np.maximum(part, 0)
    coarse = value_noise(pts, COARSE_CELL, seed)
    fx, fy, fz = np.moveaxis(np.floor(pts / FINE_CELL).astype(np.int64) + _KEY_BIAS, -1, 0)
    fine = hash01(fx, fy, fz, seed + 7)
    return 0.8 + 0.3 * coarse + 0.1 * fine


def shade(pts: np.ndarray, normals: np.ndarray, lights: np.ndarray) -> np.ndarray:
    """Ambient plus Lambert from each light with distance fall-off."""
    total = np.full(pts.shape[:-1], AMBIENT, dtype=np.float64)
    for light in lights:
        to = light - pts
        dist = np.linalg.norm(to, axis=-1)
        lam = np.clip(np.sum(to * normals, axis=-1) / np.maximum(dist, 1e-6), 0.0, 1.0)
        total += 0.9 * lam / (1.0 + 0.08 * dist**2) / len(lights) ** 0.5
    return total


def linear_colour_numpy(origin: np.ndarray, dirs: np.ndarray, depth: np.ndarray,
                        normals: np.ndarray, part: np.ndarray, albedo: np.ndarray,
                        lights: np.ndarray) -> np.ndarray:
    """The reference: (H, W, 3) float64 colour before gamma and noise."""
    pts = origin + dirs * depth[..., None]
    return albedo[part] * texture(pts, part)[..., None] * shade(pts, normals, lights)[..., None]


# ----------------------------------------------------------------------------- compiled
def _hash_one(ix, iy, iz, seed):
    h = (np.uint64(ix) * np.uint64(73856093)) ^ (np.uint64(iy) * np.uint64(19349663))
    h ^= np.uint64(iz) * np.uint64(83492791)
    h ^= np.uint64(seed) * np.uint64(2654435761)
    h ^= h >> np.uint64(13)
    h *= np.uint64(0x5BD1E995)
    h ^= h >> np.uint64(15)
    return np.float64(h & np.uint64(0xFFFFFF)) / 16777216.0


def _linear_colour(origin, dirs, depth, normals, part, albedo, lights, out):
    n = depth.shape[0]
    n_lights = lights.shape[0]
    norm_lights = n_lights ** 0.5
    last = albedo.shape[0] - 1
    bias = np.int64(_KEY_BIAS)
    for p in range(n):
        z = np.float64(depth[p])
        x0 = origin[0] + dirs[p, 0] * z
        x1 = origin[1] + dirs[p, 1] * z
        x2 = origin[2] + dirs[p, 2] * z
        # shading
        total = AMBIENT
        for li in range(n_lights):
            t0 = np.float64(lights[li, 0]) - x0
            t1 = np.float64(lights[li, 1]) - x1
            t2 = np.float64(lights[li, 2]) - x2
            dist = np.sqrt(t0 * t0 + t1 * t1 + t2 * t2)
            dot = t0 * np.float64(normals[p, 0]) + t1 * np.float64(normals[p, 1]) \
                + t2 * np.float64(normals[p, 2])
            lam = dot / max(dist, 1e-6)
            if lam < 0.0:
                lam = 0.0
            elif lam > 1.0:
                lam = 1.0
            total += 0.9 * lam / (1.0 + 0.08 * (dist * dist)) / norm_lights
        # texture
        pi = part[p]
        seed = pi if pi > 0 else 0
        g0, g1, g2 = x0 / COARSE_CELL, x1 / COARSE_CELL, x2 / COARSE_CELL
        b0, b1, b2 = np.floor(g0), np.floor(g1), np.floor(g2)
        f0, f1, f2 = g0 - b0, g1 - b1, g2 - b2
        f0 = f0 * f0 * (3 - 2 * f0)
        f1 = f1 * f1 * (3 - 2 * f1)
        f2 = f2 * f2 * (3 - 2 * f2)
        k0, k1, k2 = np.int64(b0) + bias, np.int64(b1) + bias, np.int64(b2) + bias
        coarse = 0.0
        for dx in range(2):
            wx = f0 if dx else 1 - f0
            for dy in range(2):
                wy = f1 if dy else 1 - f1
                for dz in range(2):
                    wz = f2 if dz else 1 - f2
                    coarse += wx * wy * wz * _hash_one(k0 + dx, k1 + dy, k2 + dz, seed)
        fine = _hash_one(np.int64(np.floor(x0 / FINE_CELL)) + bias,
                         np.int64(np.floor(x1 / FINE_CELL)) + bias,
                         np.int64(np.floor(x2 / FINE_CELL)) + bias, seed + 7)
        tex = 0.8 + 0.3 * coarse + 0.1 * fine
        a = pi if pi >= 0 else last
        for c in range(3):
            out[p, c] = np.float64(albedo[a, c]) * tex * total


if njit is not None:
    _hash_one = njit(cache=True, nogil=True, inline="always")(_hash_one)
    _linear_colour = njit(cache=True, nogil=True)(_linear_colour)


def linear_colour(origin: np.ndarray, dirs: np.ndarray, depth: np.ndarray,
                  normals: np.ndarray, part: np.ndarray, albedo: np.ndarray,
                  lights: np.ndarray) -> np.ndarray:
    """(H, W, 3) float64 colour before gamma and noise: per-instance ``albedo[part]`` (the
    last row for ``part`` -1) x :func:`texture` x :func:`shade` at the hit points
    ``origin + dirs * depth``; compiled, identical to :func:`linear_colour_numpy`."""
    if njit is None:  # pragma: no cover
        return linear_colour_numpy(origin, dirs, depth, normals, part, albedo, lights)
    h, w = depth.shape
    out = np.empty((h * w, 3), dtype=np.float64)
    _linear_colour(np.ascontiguousarray(origin, dtype=np.float64),
                   np.ascontiguousarray(dirs.reshape(-1, 3), dtype=np.float64),
                   np.ascontiguousarray(depth.reshape(-1)),
                   np.ascontiguousarray(normals.reshape(-1, 3)),
                   np.ascontiguousarray(part.reshape(-1)),
                   np.ascontiguousarray(albedo), np.ascontiguousarray(lights), out)
    return out.reshape(h, w, 3)
