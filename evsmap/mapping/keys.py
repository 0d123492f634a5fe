"""OctoMap voxel keys: 16 bits per axis, centred at 2**15, and their packing into one int64.

A coordinate ``x`` (metres) falls in the voxel with key ``floor(x * (1 / resolution)) + 32768``
(OctoMap's ``coordToKey``, computed by :func:`evsmap.mapping.raycast.octomap_keys`); the voxel's
centre is ``(key - 32768 + 0.5) * resolution``. Keys at tree depth ``d < 16`` keep their high
``d`` bits (the low ``16 - d`` bits are zero), as OctoMap's ``adjustKeyAtDepth`` does for the
node's first corner.

A key triple is packed as ``(kx << 32) | (ky << 16) | kz`` ("code"); sorting codes sorts by x,
then y, then z. :func:`morton` interleaves the bits instead, which orders nodes depth-first in
OctoMap's child order (child index bit 0 = x, bit 1 = y, bit 2 = z).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

TREE_DEPTH = 16
KEY_OFFSET = 1 << 15
KEY_MAX = (1 << 16) - 1


def key_to_coord(keys: np.ndarray, resolution: float, depth: int | np.ndarray = TREE_DEPTH
                 ) -> np.ndarray:
    """Centres (N, 3, float64) of the nodes with first-corner ``keys`` at tree ``depth``."""
    keys = np.asarray(keys, dtype=np.int64)
    size = (1 << (TREE_DEPTH - np.asarray(depth, dtype=np.int64)))
    if np.ndim(size):
        size = size[:, None]
    return (keys - KEY_OFFSET + size / 2.0) * resolution


def pack(keys: np.ndarray) -> np.ndarray:
    """Pack (N, 3) keys into ``int64`` codes ``(kx << 32) | (ky << 16) | kz``."""
    k = np.asarray(keys, dtype=np.int64)
    return (k[:, 0] << 32) | (k[:, 1] << 16) | k[:, 2]


def unpack(codes: np.ndarray) -> np.ndarray:
    """Inverse of :func:`pack`: ``int64`` (N, 3) keys."""
    c = np.asarray(codes, dtype=np.int64)
    return np.stack([(c >> 32) & KEY_MAX, (c >> 16) & KEY_MAX, c & KEY_MAX], axis=1)


def _spread(v: np.ndarray) -> np.ndarray:
    """Put bit i of a 16-bit value at bit 3 i."""
    v = v.astype(np.uint64) & np.uint64(0xFFFF)
    v = (v | (v << np.uint64(16))) & np.uint64(0x0000FF0000FF)
    v = (v | (v << np.uint64(8))) & np.uint64(0x00F00F00F00F)
    v = (v | (v << np.uint64(4))) & np.uint64(0x0C30C30C30C3)
    v = (v | (v << np.uint64(2))) & np.uint64(0x249249249249)
    return v


def morton(keys: np.ndarray) -> np.ndarray:
    """``uint64`` Morton codes with x in the lowest bit of each triple (OctoMap child order:
    child index = x bit + 2 * y bit + 4 * z bit), most significant level first."""
    k = np.asarray(keys)
    y, z = _spread(k[:, 1]) << np.uint64(1), _spread(k[:, 2]) << np.uint64(2)
    codes: npt.NDArray[np.uint64] = _spread(k[:, 0]) | y | z
    return codes
