"""Spatially correlated uniform fields for the oracle's error draws.

A network's errors come in patches, and a surface it gets wrong in one frame it tends to get
wrong in the next (it sees nearly the same image). The oracle draws each pixel's "is it wrong"
and "which wrong class" from uniforms that are correlated the same ways:

* the image's field: white Gaussian noise smoothed by a Gaussian of standard deviation
  ``sigma`` px (a circular convolution, by FFT, so every pixel has the same variance), scaled
  to unit variance;
* :func:`world_fields`: a Gaussian value-noise field on a 3D lattice of spacing ``scale`` metres,
  trilinearly interpolated at each pixel's back-projected point (world frame), scaled to unit
  variance at every point; the lattice values are hashes of the lattice coordinates and the
  seed, so every frame of a sequence reads the same field;
* :func:`uniform_fields`: ``sqrt(w) * world + sqrt(1 - w) * image`` through the normal CDF, a
  uniform on [0, 1) at every pixel whatever ``w`` and ``sigma`` (so the error rate stays the
  profile's accuracy) with the two kinds of correlation mixed by ``w``. Pixels without a valid
  depth read the image field alone.
"""

from __future__ import annotations

import numpy as np

from evsmap.data import Frame

_MIX = np.uint64(0x9E3779B97F4A7C15)


def _splitmix(x: np.ndarray) -> np.ndarray:
    """splitmix64's finaliser on uint64 arrays (wrapping arithmetic)."""
    with np.errstate(over="ignore"):
        x = x + _MIX
        x = (x ^ (x >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        x = (x ^ (x >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
        return x ^ (x >> np.uint64(31))


def _lattice_normals(ix: np.ndarray, iy: np.ndarray, iz: np.ndarray, key: int) -> np.ndarray:
    """A standard normal per lattice point, a function of its coordinates and ``key`` alone."""
    h = _splitmix(np.full(ix.shape, key, dtype=np.uint64))
    for coord in (ix, iy, iz):
        h = _splitmix(h ^ coord.astype(np.int64).view(np.uint64))
    from scipy import special  # scipy only where a field is drawn (`evsmap list` stays light)

    u = ((h >> np.uint64(11)).astype(np.float64) + 0.5) / float(1 << 53)
    return special.ndtri(u)


def world_points(frame: Frame) -> tuple[np.ndarray, np.ndarray]:
    """(H, W, 3) world points of the pixels and the (H, W) mask of valid depth."""
    assert frame.depth is not None and frame.intrinsics is not None  # an image frame
    depth = np.asarray(frame.depth, dtype=np.float64)
    valid = np.isfinite(depth) & (depth > 0)
    h, w = depth.shape
    k = frame.intrinsics
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    z = np.where(valid, depth, 0.0)
    cam = np.stack([(u - k.cx) / k.fx * z, (v - k.cy) / k.fy * z, z], axis=-1)
    pose = np.asarray(frame.pose, dtype=np.float64)
    return cam @ pose[:3, :3].T + pose[:3, 3], valid


_OFFSET = 1 << 20
"""Lattice coordinates are packed in 21 bits each (+- 2^20 cells: 52 km at 5 cm)."""


def _cells(points: np.ndarray, scale: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The distinct lattice cells (C, 3) of ``points`` (N, 3), each point's cell index and its
    position inside the cell (N, 3) in [0, 1)."""
    p = points / scale
    floor = np.floor(p)
    f = p - floor
    c = np.clip(floor.astype(np.int64) + _OFFSET, 0, 2 * _OFFSET - 1)
    packed = (c[:, 0] << 42) | (c[:, 1] << 21) | c[:, 2]
    keys, where = np.unique(packed, return_inverse=True)
    mask = (1 << 21) - 1
    cells = np.stack([keys >> 42, (keys >> 21) & mask, keys & mask], axis=1) - _OFFSET
    return cells, where.reshape(-1), f


def world_fields(points: np.ndarray, scale: float, keys: list[int]) -> list[np.ndarray]:
    """Unit-variance value noise at ``points`` (..., 3), one field per key: lattice spacing
    ``scale`` m, trilinear between the lattice values, which are drawn once per distinct cell
    of the points (a frame covers few cells)."""
    flat = points.reshape(-1, 3)
    cells, where, f = _cells(flat, scale)
    weights = []
    for corner in range(8):
        d = [(corner >> a) & 1 for a in range(3)]
        w = np.ones(len(flat))
        for a in range(3):
            w = w * (f[:, a] if d[a] else 1.0 - f[:, a])
        weights.append((d, w))
    norm = np.sqrt(sum(w * w for _, w in weights))
    out = []
    for key in keys:
        total = np.zeros(len(flat))
        for d, w in weights:
            n = _lattice_normals(cells[:, 0] + d[0], cells[:, 1] + d[1], cells[:, 2] + d[2], key)
            total += w * n[where]
        out.append((total / norm).reshape(points.shape[:-1]))
    return out


def _periodic_gaussian(n: int, sigma: float) -> np.ndarray:
    """The Gaussian of standard deviation ``sigma`` sampled on a circle of ``n`` px (offsets
    0..n-1, every wrap summed), summing to 1."""
    wraps = int(np.ceil(4.0 * sigma / n)) + 1
    x = np.arange(n)[None, :] + n * np.arange(-wraps, wraps + 1)[:, None]
    k = np.exp(-0.5 * (x / sigma) ** 2).sum(axis=0)
    return k / k.sum()


def _smoothed(noise: np.ndarray, sigma: float) -> np.ndarray:
    """White noise smoothed to a unit-variance field of correlation length ``sigma`` px: a
    circular convolution with the periodic Gaussian (every pixel has the same variance), by
    FFT; the variance of smoothed unit white noise is the kernel's sum of squares."""
    if sigma <= 0:
        return noise
    h, w = noise.shape
    ky, kx = _periodic_gaussian(h, sigma), _periodic_gaussian(w, sigma)
    transfer = np.fft.fft(ky).real[:, None] * np.fft.rfft(kx).real[None, :]
    smooth = np.fft.irfft2(np.fft.rfft2(noise) * transfer, s=noise.shape)
    return smooth / float(np.sqrt((ky ** 2).sum() * (kx ** 2).sum()))


class FieldMemo:
    """Fields already computed, for a caller that draws the same frames' fields under many
    settings (the oracle's fit): the smoothed image field by (frame, field, sigma), the world
    field and its points by (frame, field, scale). The random draws are made every time, so a
    memo never changes a value."""

    def __init__(self) -> None:
        self.image: dict[tuple[object, ...], np.ndarray] = {}
        self.world: dict[tuple[object, ...], np.ndarray] = {}
        self.points: dict[tuple[object, ...], tuple[np.ndarray, np.ndarray]] = {}


def _frame_key(frame: Frame) -> tuple[str, float]:
    return frame.name, frame.timestamp


def uniform_fields(rng: np.random.Generator, frame: Frame, n: int, *, sigma: float,
                   world_share: float, world_scale: float, key: int,
                   memo: FieldMemo | None = None) -> np.ndarray:
    """(n, H, W) correlated uniforms (module notes); ``key`` picks the world field (the same
    key, the same field in every frame)."""
    from scipy import special

    assert frame.depth is not None  # an image frame
    shape = frame.depth.shape
    out = np.empty((n,) + shape)
    points = valid = None
    if world_share > 0:
        if memo is None:
            points, valid = world_points(frame)
        else:
            if _frame_key(frame) not in memo.points:
                memo.points[_frame_key(frame)] = world_points(frame)
            points, valid = memo.points[_frame_key(frame)]
    scenes: list[np.ndarray] = []
    if points is not None:
        wkey = (*_frame_key(frame), n, world_scale, key)
        if memo is None or wkey not in memo.world:
            scenes = world_fields(points, world_scale, [key * 8 + i for i in range(n)])
            if memo is not None:
                memo.world[wkey] = np.stack(scenes)
        else:
            scenes = list(memo.world[wkey])
    for i in range(n):
        noise = rng.standard_normal(shape)
        ikey = (*_frame_key(frame), i, sigma, key)
        if memo is None:
            g = _smoothed(noise, sigma)
        else:
            if ikey not in memo.image:
                memo.image[ikey] = _smoothed(noise, sigma)
            g = memo.image[ikey]
        if scenes and valid is not None:
            mixed = np.sqrt(world_share) * scenes[i] + np.sqrt(1.0 - world_share) * g
            g = np.where(valid, mixed, g)
        out[i] = special.ndtr(g)
    return np.minimum(out, np.nextafter(1.0, 0.0))


__all__ = ["FieldMemo", "uniform_fields", "world_fields", "world_points"]
