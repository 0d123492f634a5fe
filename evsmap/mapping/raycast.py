"""Vectorised OctoMap ray casting: which voxels one scan frees and which it marks occupied.

:func:`scan_keys` reproduces ``OccupancyOcTreeBase::insertPointCloud``'s key sets (its
``computeUpdate`` / ``computeDiscreteUpdate`` and ``OcTreeBaseImpl::computeRayKeys``) bit for bit,
including OctoMap's float/double mix:

* Points and the origin are rounded to ``float32`` first (OctoMap's ``point3d`` is float; the
  Python bindings cast with ``<float>``). A coordinate ``x`` lies in the voxel with key
  ``floor(x * (1 / resolution)) + 2**15`` (``coordToKeyChecked``; the multiplication by the
  reciprocal rounds differently from a division at exact voxel borders). Points or origins
  outside the 16-bit key range are skipped as OctoMap skips them (it only prints a warning);
  non-finite points are dropped.
* ``discretize=True``: endpoints are first reduced to the (float) centres of their unique voxels.
* Per point, with ``d = p - origin`` in float and ``|d|`` the double square root of the float sum
  of squares: if ``max_range < 0`` or ``|d| <= max_range`` the ray ``origin -> p`` frees its voxels
  and ``p``'s voxel is occupied; otherwise the ray is cut at ``origin + d / |d| * max_range``
  (float arithmetic) and only frees voxels - the voxel holding the cut end is *not* freed, as for
  any ray.
* Ray keys (Amanatides-Woo 3D DDA, as ``computeRayKeys``): nothing when the origin and the end
  share a voxel; else the origin's voxel and every voxel entered after it, stopping (and not
  adding) when the voxel is the end's voxel or when the ray would leave the voxel it has just
  entered beyond the ray length (OctoMap's guard against rounding). The per-axis crossing
  parameters are ``tMax += tDelta`` in double, accumulated sequentially exactly as OctoMap does.
* **Tie-breaking**: when two or three axes reach a voxel border at the same (double) ``t``, the
  step is taken along the axis with the *highest* index first (z before y before x), which is what
  OctoMap's ``if (tMax[0] < tMax[1]) ... else ...`` comparison chain does.
* Keys are gathered into sets, so each voxel is updated once per scan, and a voxel that is both
  free and occupied in one scan is only occupied.

Vectorisation: the DDA of a ray is a merge of three increasing sequences of border-crossing
parameters (one per axis). For a chunk of rays the sequences are laid out as rows of a padded
matrix (axis 2, then 1, then 0), sorted per row with a stable sort (so ties keep the z-y-x order),
and cumulative sums of the per-axis key increments give every voxel of every ray; the first
stopping position per row is found with ``argmax``. Rays are processed in chunks of similar length
so that the matrices stay below :data:`CHUNK_ELEMENTS` cells (a few hundred MB at most), and the
visited voxels are de-duplicated in a dense bit grid over the scan's bounding box (or with
``np.unique`` when that box is too large).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from evsmap.data import Frame
from evsmap.errors import InvalidDataError
from evsmap.geometry import backproject
from evsmap.mapping.kernels import Kernels, grid_codes, trace
from evsmap.mapping.keys import KEY_MAX, KEY_OFFSET, pack, unpack

CHUNK_ELEMENTS = 1 << 21
"""Cells (rays x padded crossings) per chunk; about 60 bytes of temporaries each."""

DENSE_GRID_LIMIT = 1 << 28
"""Largest bounding box (voxels) de-duplicated with a dense ``bool`` grid (256 MB)."""

_SHIFTS = np.array([32, 16, 0], dtype=np.int64)


class ScanKeys(NamedTuple):
    """Voxel codes (:func:`evsmap.mapping.keys.pack`) touched by one scan, each sorted and unique;
    the two sets are disjoint."""

    free: np.ndarray
    occupied: np.ndarray


def octomap_keys(points: np.ndarray, resolution: float) -> tuple[np.ndarray, np.ndarray]:
    """OctoMap's ``coordToKeyChecked``: ``int64`` (N, 3) keys ``floor(x * (1/res)) + 2**15`` of
    the coordinates as given (cast ``float32`` points first to mimic ``point3d``), and a mask of
    the rows whose three keys are inside ``[0, 65535]``."""
    rf = 1.0 / float(resolution)
    scaled = np.asarray(points, dtype=np.float64) * rf
    np.floor(scaled, out=scaled)
    np.clip(scaled, -KEY_OFFSET - 1, KEY_MAX - KEY_OFFSET + 1, out=scaled)  # also maps inf
    keys = scaled.astype(np.int64)
    keys += KEY_OFFSET
    bad = (keys < 0) | (keys > KEY_MAX)
    ok: npt.NDArray[np.bool_] = ~np.any(bad, axis=1)
    if not ok.all():
        keys[~ok] = 0
    return keys, ok


def vector_norm(d: np.ndarray) -> np.ndarray:
    """OctoMap's ``Vector3::norm``: float sum of squares, double square root."""
    sq = (d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1]) + d[:, 2] * d[:, 2]
    norm: npt.NDArray[np.float64] = np.sqrt(sq.astype(np.float64))
    return norm


def scan_keys(points: np.ndarray, origin: np.ndarray, resolution: float, *,
              max_range: float = -1.0, discretize: bool = False,
              kernels: Kernels = "compiled") -> ScanKeys:
    """Free and occupied voxels of one scan, exactly as OctoMap's ``insertPointCloud``.

    Args:
        points: (N, 3) measurement end points in world coordinates (metres).
        origin: (3,) sensor origin in world coordinates.
        resolution: voxel edge length in metres.
        max_range: rays longer than this are cut and only free space (negative: no limit).
        discretize: reduce the end points to unique voxel centres first (OctoMap's
            ``computeDiscreteUpdate``), far fewer rays for dense clouds.
        kernels: walk the rays with the compiled kernel (:mod:`evsmap.mapping.kernels`) or the
            pure-numpy merge (``"reference"``); the same sets.
    """
    resolution = float(resolution)
    if not resolution > 0:
        raise ValueError(f"resolution must be positive, got {resolution}")
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    pts = pts[np.all(np.isfinite(pts), axis=1)].astype(np.float32)
    org = np.asarray(origin, dtype=np.float64).reshape(3)
    if not np.all(np.isfinite(org)):
        raise ValueError(f"origin must be finite, got {org.tolist()}")
    org = org.astype(np.float32)
    empty = np.zeros(0, dtype=np.int64)
    if discretize and len(pts):
        keys, ok = octomap_keys(pts, resolution)
        keys = unpack(np.unique(pack(keys[ok])))
        pts = ((keys - KEY_OFFSET + 0.5) * resolution).astype(np.float32)
    if not len(pts):
        return ScanKeys(empty, empty)

    dist = vector_norm(pts - org)
    inside = dist <= max_range if max_range >= 0 else np.ones(len(pts), dtype=bool)
    okeys, ok = octomap_keys(pts[inside], resolution)
    occupied = pack(okeys[ok])
    if occupied.size > 1 and not np.all(occupied[1:] > occupied[:-1]):
        occupied = np.unique(occupied)  # (discretized points come sorted and unique already)

    ends = pts.copy()
    if not np.all(inside):
        far = ~inside
        direction = (pts[far] - org) / dist[far].astype(np.float32)[:, None]
        ends[far] = org + direction * np.float32(max_range)
    free = _ray_keys(org, ends, resolution, occupied, kernels)
    return ScanKeys(free, occupied)


class _Space(NamedTuple):
    """A linear index over a box of keys: ``index = sum((key - base) * strides)``."""

    base: np.ndarray
    shape: np.ndarray
    strides: np.ndarray
    size: int  # 0: the box is the whole key space and indices are packed codes

    def linear(self, keys: np.ndarray) -> npt.NDArray[np.int64]:
        index: npt.NDArray[np.int64] = (keys - self.base) @ self.strides
        return index

    def codes(self, index: np.ndarray) -> np.ndarray:
        if not self.size:
            return index
        k0, rem = np.divmod(index, self.strides[0])
        k1, k2 = np.divmod(rem, self.strides[1])
        return pack(np.stack([k0, k1, k2], axis=1) + self.base)


def _space(lo: np.ndarray, hi: np.ndarray) -> _Space:
    lo = np.maximum(lo - 2, 0)
    hi = np.minimum(hi + 2, KEY_MAX)
    shape = hi - lo + 1
    size = int(np.prod(shape))
    if size <= DENSE_GRID_LIMIT:
        strides = np.array([shape[1] * shape[2], shape[2], 1], dtype=np.int64)
        return _Space(lo.astype(np.int64), shape.astype(np.int64), strides, size)
    return _Space(np.zeros(3, dtype=np.int64), np.full(3, KEY_MAX + 1, dtype=np.int64),
                  np.int64(1) << _SHIFTS, 0)


def _ray_keys(org: np.ndarray, ends: np.ndarray, resolution: float,
              occupied: np.ndarray, kernels: Kernels = "compiled") -> np.ndarray:
    """Sorted unique codes of the voxels freed by the rays ``org -> ends`` (float32), minus
    ``occupied``."""
    empty = np.zeros(0, dtype=np.int64)
    ko, ok = octomap_keys(org[None, :], resolution)
    if not ok[0]:
        return empty
    ko = ko[0]
    ke, ok = octomap_keys(ends, resolution)
    ok &= np.any(ke != ko, axis=1)
    ends, ke = ends[ok], ke[ok]
    if not len(ends):
        return empty

    # ---- per-ray DDA set-up (computeRayKeys' initialisation), float/double as OctoMap
    d = ends - org
    length = vector_norm(d).astype(np.float32)
    direction = (d / length[:, None]).astype(np.float64)
    step = np.sign(direction).astype(np.int64)
    moving = step != 0
    half = float(np.float32(resolution * 0.5))
    border = ((ko - KEY_OFFSET) + 0.5) * resolution + step * half
    with np.errstate(divide="ignore", invalid="ignore"):
        tmax = np.where(moving, (border - org.astype(np.float64)) / direction, np.inf)
        tdelta = np.where(moving, resolution / np.abs(direction), np.inf)
    # Crossings generated per axis: the |ke - ko| that reach the end voxel plus two more, enough
    # for the rounding-guard stop to trigger (the (n+2)-th crossing is a full voxel past the end).
    counts = np.where(moving, np.abs(ke - ko) + 2, 0)

    lo = np.minimum(ke.min(axis=0), ko)
    hi = np.maximum(ke.max(axis=0), ko)
    space = _space(lo, hi)
    origin_index = space.linear(ko)
    end_index = space.linear(ke)
    increments = step * space.strides  # index change of one step along each axis

    walk = _walk_compiled if kernels == "compiled" and trace is not None else _walk_reference
    return walk(_Rays(tmax, tdelta, counts, length, increments, end_index - origin_index),
                origin_index, space, occupied)


class _Rays(NamedTuple):
    """The DDA start values of a scan's rays (one row a ray): ``tMax``, ``tDelta``, crossings
    per axis, length, index change of one step per axis, and the end voxel's index offset from
    the origin voxel."""

    tmax: np.ndarray
    tdelta: np.ndarray
    counts: np.ndarray
    length: np.ndarray
    increments: np.ndarray
    end_offset: np.ndarray


def _walk_compiled(rays: _Rays, origin_index: np.ndarray, space: _Space,
                   occupied: np.ndarray) -> np.ndarray:
    """:func:`_ray_keys`'s walk with the compiled :func:`~evsmap.mapping.kernels.trace`."""
    total = rays.counts.sum(axis=1)
    grid = np.zeros(space.size, dtype=bool) if space.size else np.zeros(0, dtype=bool)
    out = np.empty(0 if space.size else int(total.sum()), dtype=np.int64)
    n = trace(rays.tmax, rays.tdelta, total, rays.length.astype(np.float64), rays.increments,
              rays.end_offset, origin_index, grid, out)
    if space.size:
        return _grid_free(grid, origin_index, space, occupied, compiled=True)
    return _unique_free([out[:n]], origin_index, occupied)


def _walk_reference(rays: _Rays, origin_index: np.ndarray, space: _Space,
                    occupied: np.ndarray) -> np.ndarray:
    """:func:`_ray_keys`'s walk in numpy: chunks of rays of similar length, each merged by
    :func:`_chunk` within :data:`CHUNK_ELEMENTS` cells."""
    total = rays.counts.sum(axis=1)
    order = np.argsort(total, kind="stable")
    total_sorted = total[order]
    grid = np.zeros(space.size, dtype=bool) if space.size else None
    parts: list[np.ndarray] = []
    start, n = 0, len(order)
    while start < n:
        stop = min(n, start + max(1, CHUNK_ELEMENTS // (int(total_sorted[start]) + 1)))
        while stop - start > 1 and (stop - start) * (int(total_sorted[stop - 1]) + 1) > \
                CHUNK_ELEMENTS:
            stop = start + max(1, CHUNK_ELEMENTS // (int(total_sorted[stop - 1]) + 1))
        chunk = order[start:stop]
        visited = _chunk(rays.tmax[chunk], rays.tdelta[chunk], rays.counts[chunk],
                         rays.length[chunk], rays.increments[chunk], rays.end_offset[chunk])
        visited += origin_index
        if grid is not None:
            grid[visited] = True
        else:
            parts.append(np.unique(visited))
        start = stop
    if grid is not None:
        return _grid_free(grid, origin_index, space, occupied, compiled=False)
    return _unique_free(parts, origin_index, occupied)


def _grid_free(grid: np.ndarray, origin_index: np.ndarray, space: _Space, occupied: np.ndarray,
               *, compiled: bool) -> np.ndarray:
    """The free codes of a grid of the voxels the rays entered: with the origin's, without the
    occupied ones."""
    grid[origin_index] = True
    if len(occupied):
        _clear_occupied(grid, space, occupied)
    return _grid_codes(grid, space, compiled)


def _unique_free(parts: list[np.ndarray], origin_index: np.ndarray,
                 occupied: np.ndarray) -> np.ndarray:
    """The free codes (the whole key space's) of the voxels the rays entered, listed in
    ``parts``: with the origin's, without the occupied ones."""
    parts.append(np.array([origin_index], dtype=np.int64))
    free = np.unique(np.concatenate(parts))
    if len(occupied):
        free = free[~np.isin(free, occupied, assume_unique=True)]
    return free


def _clear_occupied(grid: np.ndarray, space: _Space, occupied: np.ndarray) -> None:
    """Occupied wins: unmark the occupied voxels (the end voxels of in-range rays lie inside the
    box)."""
    keys = unpack(occupied)
    inside = np.all((keys >= space.base) & (keys < space.base + space.shape), axis=1)
    grid[space.linear(keys[inside])] = False


def _grid_codes(grid: np.ndarray, space: _Space, compiled: bool,
                block: int = 1 << 22) -> np.ndarray:
    """Sorted codes of the set cells of a dense grid, converted a block at a time (by the
    compiled :func:`~evsmap.mapping.kernels.grid_codes` when ``compiled``)."""
    if compiled and grid_codes is not None:
        codes: npt.NDArray[np.int64] = grid_codes(grid, *(int(b) for b in space.base),
                                                  int(space.shape[1]), int(space.shape[2]))
        return codes
    out = np.empty(np.count_nonzero(grid), dtype=np.int64)
    pos = 0
    for start in range(0, grid.size, block):
        index = np.flatnonzero(grid[start:start + block])
        index += start
        out[pos:pos + index.size] = space.codes(index)
        pos += index.size
    return out


def _chunk(tmax: np.ndarray, tdelta: np.ndarray, counts: np.ndarray, length: np.ndarray,
           increments: np.ndarray, end_offset: np.ndarray) -> np.ndarray:
    """Index offsets (relative to the origin voxel) of the voxels each ray of a chunk enters
    before it stops; the origin voxel itself is not included."""
    rays = len(tmax)
    width = int(counts.sum(axis=1).max()) + 1  # at least one padding column per row
    # row r: its axis-2 crossings, then axis-1, then axis-0 (the tie-break order, which the stable
    # sort keeps), then +inf padding
    blocks, valid, bounds = [], [], []
    start = np.zeros(rays, dtype=np.int64)
    for axis in (2, 1, 0):
        w = int(counts[:, axis].max())
        if w:
            block = np.empty((rays, w), dtype=np.float64)
            block[:, 0] = tmax[:, axis]
            block[:, 1:] = tdelta[:, axis, None]
            np.cumsum(block, axis=1, out=block)  # sequential, as OctoMap's tMax += tDelta
            blocks.append(block)
            valid.append(np.arange(w)[None, :] < counts[:, axis, None])
        start += counts[:, axis]
        bounds.append(start.copy())
    t = np.full((rays, width), np.inf)
    t[np.arange(width)[None, :] < start[:, None]] = np.concatenate(blocks, axis=1)[
        np.concatenate(valid, axis=1)]
    del blocks, valid

    order = np.argsort(t, axis=1, kind="stable")
    # rays stop once the crossing after the current step lies beyond the ray length: with the
    # crossings sorted that is step (number of crossings <= length) - 1 (the first step is always
    # taken), unless the end voxel is entered earlier
    first = np.maximum(np.count_nonzero(t <= length[:, None].astype(np.float64), axis=1) - 1, 0)
    del t
    # voxel index after each step: cumulative per-axis increments along the sorted crossings
    flat = (order >= bounds[0][:, None]).astype(np.int64)  # 0: axis 2, 1: axis 1, 2: axis 0
    flat += order >= bounds[1][:, None]
    del order
    flat += (np.arange(rays, dtype=np.int64) * 3)[:, None]
    index = np.take(increments[:, ::-1].ravel(), flat)
    del flat
    np.cumsum(index, axis=1, out=index)
    at_end = index == end_offset[:, None]
    end_step = np.where(at_end.any(axis=1), np.argmax(at_end, axis=1), width)
    del at_end
    first = np.minimum(first, end_step)
    keep = np.arange(width)[None, :] < first[:, None]
    entered: npt.NDArray[np.int64] = index[keep]
    return entered


def frame_points(frame: Frame, *, stride: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """World points (N, 3 float64) of the frame's valid depth pixels (every ``stride``-th row and
    column) and the camera centre (the pose's translation), the ray origin."""
    if stride < 1:
        raise ValueError(f"stride must be a positive integer, got {stride}")
    depth, intrinsics = frame.depth, frame.intrinsics
    if depth is None or intrinsics is None:
        raise InvalidDataError(f"frame_points needs an image frame; frame {frame.name!r} is a "
                               f"point cloud")
    mask = None
    if stride > 1:
        mask = np.zeros(depth.shape, dtype=bool)
        mask[::stride, ::stride] = True
    cam = backproject(depth, intrinsics, mask=mask)
    # camera -> world without a BLAS (N, 3) @ (3, 3) product: on a busy 2-core machine
    # OpenBLAS's threads made that take ~130 ms per 640x480 frame instead of ~2 ms
    rot, origin = frame.pose[:3, :3], frame.pose[:3, 3].copy()
    points = np.empty_like(cam)
    for i in range(3):
        points[:, i] = cam[:, 0] * rot[i, 0] + cam[:, 1] * rot[i, 1] + cam[:, 2] * rot[i, 2] \
            + origin[i]
    return points, origin
