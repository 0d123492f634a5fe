"""OctoMap-compatible occupancy of the finest voxels, stored sparsely and updated a scan at a time.

:class:`OccupancyMap` keeps the leaves of an OctoMap ``OcTree`` expanded to depth 16: a sorted
``int64`` array of voxel codes (:func:`evsmap.mapping.keys.pack`) and a ``float32`` log-odds array.
Pruning and inner nodes are a separate concern (a pruned OctoMap node is equivalent to its 8**k
equal leaves, and OctoMap expands it again as soon as one of them changes), so after the same
scans both hold the same occupancy for every voxel.

The update is OctoMap's ``insertPointCloud`` with ``lazy_eval`` off: the scan's free and occupied
key sets (:func:`evsmap.mapping.raycast.scan_keys`) are each applied once, a new leaf starts at
log-odds 0, and ``L <- clamp(L + l)`` in ``float32`` with ``l`` the hit or miss log-odds and the
clamping bounds, all rounded to ``float32`` as OctoMap stores them. A leaf is occupied when its
log-odds are ``>=`` the threshold's (OctoMap's ``isNodeOccupied``).

Other per-leaf data (colour, semantics) can live beside the log-odds as *payloads*
(:meth:`OccupancyMap.add_payload`); they stay aligned with the leaves when new leaves are inserted,
and :class:`ScanUpdate` tells an updater which leaves a scan touched.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from evsmap.data import Frame
from evsmap.interfaces import FREE, OCCUPIED, UNKNOWN, PointQuery
from evsmap.mapping.kernels import grow_rows, sorted_index
from evsmap.mapping.keys import pack
from evsmap.mapping.raycast import frame_points, octomap_keys, scan_keys
from evsmap.mapping.sensor_model import OccupancyParams, logodds

__all__ = ["OccupancyMap", "OccupancyParams", "ScanUpdate", "logodds"]


@dataclass(frozen=True)
class ScanUpdate:
    """Which leaves one scan updated, as indices into the map's arrays *after* the update.

    Attributes:
        occupied_index: ``int64`` indices of the leaves updated as hits (end points), ascending.
        free_index: ``int64`` indices of the leaves updated as misses (traversed), ascending.
        new_mask: ``bool`` (num_leaves,) - leaves created by this scan.
    """

    occupied_index: np.ndarray
    free_index: np.ndarray
    new_mask: np.ndarray = field(repr=False)

    @property
    def num_new(self) -> int:
        """Number of leaves the scan created."""
        return int(np.count_nonzero(self.new_mask))

    @property
    def occupied_new(self) -> np.ndarray:
        """``bool`` aligned with :attr:`occupied_index`: the leaf was created by this scan."""
        new: npt.NDArray[np.bool_] = self.new_mask[self.occupied_index]
        return new

    @property
    def free_new(self) -> np.ndarray:
        """``bool`` aligned with :attr:`free_index`: the leaf was created by this scan."""
        new: npt.NDArray[np.bool_] = self.new_mask[self.free_index]
        return new


class OccupancyMap:
    """Finest-level occupancy leaves (sorted codes + ``float32`` log-odds) of an OctoMap-style map.

    Args:
        resolution: voxel edge length in metres.
        params: the sensor model (:class:`OccupancyParams`, OctoMap's defaults when omitted).
    """

    def __init__(self, resolution: float, params: OccupancyParams | None = None) -> None:
        if isinstance(resolution, bool) or not isinstance(resolution, (int, float, np.floating)) \
                or not (math.isfinite(resolution) and resolution > 0):
            raise ValueError(f"resolution must be a positive number of metres, got {resolution!r}")
        self.resolution = float(resolution)
        self.params = params if params is not None else OccupancyParams()
        if not isinstance(self.params, OccupancyParams):
            raise ValueError(f"params must be OccupancyParams, got {type(self.params).__name__}")
        p = self.params
        self._hit = np.float32(p.hit_logodds)
        self._miss = np.float32(p.miss_logodds)
        self._lo = np.float32(p.clamp_min_logodds)
        self._hi = np.float32(p.clamp_max_logodds)
        self._threshold = np.float32(p.threshold_logodds)
        self._codes = np.zeros(0, dtype=np.int64)
        self._logodds = np.zeros(0, dtype=np.float32)
        self._payloads: dict[str, np.ndarray] = {}
        self._fills: dict[str, np.ndarray] = {}

    @classmethod
    def from_leaves(cls, resolution: float, codes: np.ndarray, logodds: np.ndarray,
                    params: OccupancyParams | None = None) -> OccupancyMap:
        """A map holding the given finest-level leaves (codes in any order, unique)."""
        codes = np.asarray(codes, dtype=np.int64).ravel()
        values = np.asarray(logodds, dtype=np.float32).ravel()
        if codes.shape != values.shape:
            raise ValueError(f"{codes.size} codes but {values.size} log-odds values")
        order = np.argsort(codes, kind="stable")
        codes = codes[order]
        if codes.size > 1 and np.any(codes[1:] == codes[:-1]):
            raise ValueError("leaf codes must be unique")
        out = cls(resolution, params)
        out._codes = codes
        out._logodds = values[order].copy()
        return out

    # ------------------------------------------------------------------ accessors
    @property
    def num_leaves(self) -> int:
        return int(self._codes.size)

    def __len__(self) -> int:
        return self.num_leaves

    @property
    def codes(self) -> np.ndarray:
        """Sorted ``int64`` leaf codes (read-only view)."""
        v = self._codes.view()
        v.flags.writeable = False
        return v

    @property
    def logodds(self) -> np.ndarray:
        """``float32`` log-odds aligned with :attr:`codes` (read-only view)."""
        v = self._logodds.view()
        v.flags.writeable = False
        return v

    def logodds_for_writing(self) -> np.ndarray:
        """The ``float32`` log-odds array itself (writable), for an updater that derives a
        leaf's occupancy from its own state (``multiclass-bayes``: from the class vector)
        instead of OctoMap's hit/miss update. Valid until the next :meth:`apply` grows the
        arrays."""
        return self._logodds

    def payload(self, name: str) -> np.ndarray:
        """The per-leaf array registered as ``name`` (writable, aligned with :attr:`codes`)."""
        try:
            return self._payloads[name]
        except KeyError:
            raise KeyError(f"no payload {name!r} (registered: {sorted(self._payloads)})") from None

    @property
    def payload_names(self) -> tuple[str, ...]:
        return tuple(self._payloads)

    def add_payload(self, name: str, dtype: np.dtype | type, shape: tuple[int, ...] = (),
                    fill: object = 0) -> np.ndarray:
        """Register a per-leaf array of ``dtype`` and per-leaf ``shape``; existing and future
        leaves start at ``fill``. Returns the array (it is replaced when leaves are inserted, so
        fetch it again with :meth:`payload` after an update)."""
        if name in self._payloads:
            raise ValueError(f"payload {name!r} already registered")
        shape = (int(shape),) if isinstance(shape, (int, np.integer)) else \
            tuple(int(s) for s in shape)
        fill_value = np.full(shape, fill, dtype=dtype)
        self._fills[name] = fill_value
        arr = np.empty((self.num_leaves, *shape), dtype=dtype)
        arr[...] = fill_value
        self._payloads[name] = arr
        return arr

    def index(self, codes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Positions of ``codes`` among the leaves and a mask of those that exist (positions of
        missing codes are meaningless)."""
        codes = np.asarray(codes, dtype=np.int64)
        if sorted_index is not None:
            pos, found = sorted_index(self._codes, codes.ravel())
            return pos.reshape(codes.shape), found.reshape(codes.shape)
        pos = np.searchsorted(self._codes, codes)
        found = np.zeros(codes.shape, dtype=bool)
        inside = pos < self._codes.size
        found[inside] = self._codes[pos[inside]] == codes[inside]
        return pos, found

    # ------------------------------------------------------------------ updates
    def insert_leaves(self, codes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Make sure leaves with the sorted unique ``codes`` exist (new ones at log-odds 0 and the
        payload fills); returns their indices in the arrays after the insertion and a mask
        (aligned with ``codes``) of those it created."""
        return self._insert(np.asarray(codes, dtype=np.int64))

    def _insert(self, codes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Insert the missing ones of the sorted unique ``codes``; their indices afterwards and a
        mask of those that were created."""
        pos, found = self.index(codes)
        new = ~found
        count = int(np.count_nonzero(new))
        index = pos + np.cumsum(new) - new  # shifted by the new leaves inserted before
        if count:
            created = index[new]
            total = len(self._codes) + count
            old = None  # without the kernel: one mask of where the old rows go, for all arrays
            if grow_rows is None:
                old = np.ones(total, dtype=bool)
                old[created] = False

            def grow(arr: np.ndarray, fill: npt.ArrayLike) -> np.ndarray:
                out = np.empty((total, *arr.shape[1:]), dtype=arr.dtype)
                if old is None:
                    width = int(np.prod(arr.shape[1:], dtype=np.int64))
                    fill = np.asarray(fill, dtype=arr.dtype)
                    rows = len(fill) if fill.ndim == arr.ndim else 1
                    fill = np.ascontiguousarray(
                        np.broadcast_to(fill.reshape(rows, -1), (rows, width)))
                    grow_rows(arr.reshape(len(arr), width), created, fill,
                              out.reshape(len(out), width))
                    return out
                out[old] = arr
                out[created] = fill
                return out

            self._codes = grow(self._codes, codes[new])
            self._logodds = grow(self._logodds, np.float32(0.0))
            for name, arr in self._payloads.items():
                self._payloads[name] = grow(arr, self._fills[name])
        return index, new

    def insert_scan(self, points: np.ndarray, origin: np.ndarray, *, max_range: float = -1.0,
                    discretize: bool = False) -> ScanUpdate:
        """Integrate one scan (world points and sensor origin) as OctoMap's ``insertPointCloud``."""
        keys = scan_keys(points, origin, self.resolution, max_range=max_range,
                         discretize=discretize)
        return self.apply(keys.free, keys.occupied)

    def insert_frame(self, frame: Frame, *, max_range: float = -1.0, discretize: bool = False,
                     stride: int = 1) -> ScanUpdate:
        """Integrate a frame's valid depth pixels (every ``stride``-th row and column) as a scan
        from the camera centre."""
        points, origin = frame_points(frame, stride=stride)
        return self.insert_scan(points, origin, max_range=max_range, discretize=discretize)

    def apply(self, free: np.ndarray, occupied: np.ndarray) -> ScanUpdate:
        """Apply one miss to each ``free`` code and one hit to each ``occupied`` code (sorted,
        unique, disjoint sets, as :func:`evsmap.mapping.raycast.scan_keys` returns)."""
        free = np.asarray(free, dtype=np.int64)
        occupied = np.asarray(occupied, dtype=np.int64)
        # merge the two sorted sets
        at = np.searchsorted(free, occupied) + np.arange(occupied.size)
        is_occupied = np.zeros(free.size + occupied.size, dtype=bool)
        is_occupied[at] = True
        codes = np.empty(is_occupied.size, dtype=np.int64)
        codes[at] = occupied
        codes[~is_occupied] = free
        if codes.size > 1 and not np.all(codes[1:] > codes[:-1]):
            raise ValueError("free and occupied codes must be sorted, unique and disjoint")
        index, new = self._insert(codes)
        new_mask = np.zeros(self.num_leaves, dtype=bool)
        new_mask[index[new]] = True
        free_index = index[~is_occupied]
        occ_index = index[is_occupied]
        lo, hi, values = self._lo, self._hi, self._logodds
        values[free_index] = np.clip(values[free_index] + self._miss, lo, hi)
        values[occ_index] = np.clip(values[occ_index] + self._hit, lo, hi)
        return ScanUpdate(occupied_index=occ_index, free_index=free_index, new_mask=new_mask)

    # ------------------------------------------------------------------ queries
    def classify_logodds(self, values: np.ndarray) -> np.ndarray:
        """``int8`` FREE / OCCUPIED of log-odds values (occupied iff ``>=`` the threshold)."""
        return np.where(np.asarray(values) >= self._threshold, OCCUPIED, FREE).astype(np.int8)

    def classify(self, codes: np.ndarray) -> np.ndarray:
        """``int8`` state of the voxels with ``codes``: -1 unknown, 0 free, 1 occupied."""
        codes = np.asarray(codes, dtype=np.int64)
        pos, found = self.index(codes)
        state = np.full(codes.shape, UNKNOWN, dtype=np.int8)
        state[found] = self.classify_logodds(self._logodds[pos[found]])
        return state

    def query(self, points: np.ndarray) -> PointQuery:
        """State and occupancy probability at world ``points`` (N x 3); the voxel of a point is
        found as OctoMap's ``search`` does; points outside the map are unknown."""
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        finite = np.all(np.isfinite(pts), axis=1)
        keys, ok = octomap_keys(np.where(finite[:, None], pts, 0.0), self.resolution)
        ok &= finite
        pos, found = self.index(pack(keys))
        found &= ok
        n = len(pts)
        state = np.full(n, UNKNOWN, dtype=np.int8)
        prob = np.full(n, np.nan, dtype=np.float32)
        values = self._logodds[pos[found]]
        state[found] = self.classify_logodds(values)
        prob[found] = (1.0 - 1.0 / (1.0 + np.exp(values.astype(np.float64)))).astype(np.float32)
        return PointQuery(state=state, probability=prob, label=np.full(n, -1, dtype=np.int16))

    def state_counts(self) -> dict[str, int]:
        """Number of free and occupied leaves."""
        occ = int(np.count_nonzero(self._logodds >= self._threshold))
        return {"free": self.num_leaves - occ, "occupied": occ}
