"""OctoMap's ``.ot`` and ``.bt`` octree files, byte-compatible, read and written with numpy.

``.ot`` (``AbstractOcTree::write`` / ``OcTreeBaseImpl::writeNodesRecurs``)::

    # Octomap OcTree file
    # (feel free to add / change comments, but leave the first line as it is!)
    #
    id <tree id>
    size <number of nodes>
    res <resolution, C++ ostream default = printf %g>
    data
    <per node in depth-first pre-order: node data, then 1 byte child mask (bit i = child i
     exists); children follow in child order 0..7>

Node data (``writeData``, native = little-endian): ``OcTree``: float32 log-odds (5 B per node);
``ColorOcTree``: float32 log-odds + uint8 r, g, b (8 B per node). Any other tree id written
here is a custom layout: float32 log-odds + one fixed-size little-endian payload record (a numpy
dtype, e.g. the semantics of a voxel), + the mask byte. The record of a tree id is its
registered node type's (:data:`evsmap.mapping.node_type.NODE_TYPES`, keyed by the file's id) or
one the caller passes (``payload_format``).

``.bt`` (``AbstractOccupancyOcTree::writeBinary`` / ``OccupancyOcTreeBase::writeBinaryNode``):
the same header with first line ``# Octomap OcTree binary file``, then per node that has
children (and always for the root), in pre-order, 2 bytes ``child1to4``, ``child5to8``: child i
uses bits 2 (i mod 4) and 2 (i mod 4) + 1 of byte i // 4, read as the number
``bit(2i) + 2 * bit(2i+1)``: 0 unknown (no child), 1 free leaf, 2 occupied leaf, 3 inner node.
Before writing, the tree is converted to maximum likelihood (every node's log-odds -> clamping
max if ``>= occupancy threshold`` else clamping min) and pruned with OctoMap's ``prune()``
(levels 15..1, stopping at the first level that pruned nothing, the root never pruned).
Reading sets leaves to the clamping max/min log-odds, inner nodes to the max of their children
and the root to the clamping max (``readBinaryNode`` never updates the root).

Parsing the pre-order stream is vectorised: records have a fixed size, so node k starts at
``k * record_size``; the tree structure is rebuilt from the child counts by repeatedly
contracting nodes whose children are all leaves (one numpy pass per tree level, at most 16),
then depths and keys are filled in level by level.

Every read error (missing or truncated file, wrong header, size mismatch, malformed stream)
raises :class:`evsmap.errors.DataFormatError` naming the file. Writes are atomic (temporary
file + ``os.replace``) and return the number of bytes written.
"""

from __future__ import annotations

import os
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import DTypeLike

from evsmap.errors import DataFormatError, InvalidDataError
from evsmap.fileio import atomic_write
from evsmap.mapping.keys import TREE_DEPTH
from evsmap.mapping.node_type import COLOR_FORMAT, NODE_TYPES
from evsmap.mapping.sensor_model import OCTOMAP
from evsmap.mapping.tree import Tree, _codes_of_morton

__all__ = [
    "COLOR_FORMAT",
    "OctreeFile",
    "bt_bytes",
    "logodds",
    "ot_bytes",
    "parse_bt",
    "parse_ot",
    "read_bt",
    "read_ot",
    "to_max_likelihood",
    "write_bt",
    "write_ot",
]

OT_HEADER = b"# Octomap OcTree file"
BT_HEADER = b"# Octomap OcTree binary file"
_COMMENT = b"\n# (feel free to add / change comments, but leave the first line as it is!)\n#\n"

_BUILTIN = {"OcTree": None, "ColorOcTree": COLOR_FORMAT}

# OctoMap's AbstractOccupancyOcTree defaults (probabilities).
DEFAULT_OCCUPANCY_THRES = OCTOMAP.occupancy_threshold
DEFAULT_CLAMP_MIN = OCTOMAP.clamp_min
DEFAULT_CLAMP_MAX = OCTOMAP.clamp_max


class OctreeFile(NamedTuple):
    """What :func:`read_ot` / :func:`read_bt` return."""

    tree_id: str
    resolution: float
    tree: Tree


def logodds(p: float) -> np.float32:
    """OctoMap's ``logodds(double)``: ``(float) log(p / (1 - p))``."""
    return np.float32(np.log(p / (1.0 - p)))


# --------------------------------------------------------------------------- small helpers

_POPCOUNT = np.array([bin(i).count("1") for i in range(256)], dtype=np.int64)


def _nth_bit_table() -> np.ndarray:
    """``T[mask, r]`` = index of the r-th set bit of ``mask`` (8 where there is none)."""
    bits = (np.arange(256)[:, None] >> np.arange(8)) & 1
    keyed = np.where(bits == 1, np.arange(8), 8 + np.arange(8))
    t = np.sort(keyed, axis=1)
    return np.where(t < 8, t, 8).astype(np.int64)


_NTH_BIT = _nth_bit_table()


def _fmt_res(resolution: float) -> bytes:
    return format(float(resolution), "g").encode("ascii")


def _header(magic: bytes, tree_id: str, size: int, resolution: float) -> bytes:
    return (magic + _COMMENT + b"id " + tree_id.encode("ascii") + b"\nsize "
            + str(int(size)).encode("ascii") + b"\nres " + _fmt_res(resolution) + b"\ndata\n")


def _check_write_args(tree: Tree, resolution: float, tree_id: str) -> None:
    if not isinstance(tree, Tree):
        raise InvalidDataError(f"expected an evsmap.mapping.tree.Tree, got {type(tree).__name__}")
    if not (np.isfinite(resolution) and resolution > 0):
        raise InvalidDataError(f"resolution must be a positive number, got {resolution!r}")
    if (not isinstance(tree_id, str) or not tree_id or not tree_id.isascii()
            or re.search(r"\s", tree_id) or tree_id.startswith("#")):
        raise InvalidDataError(f"tree id must be one ASCII word, got {tree_id!r}")


def _atomic_write(path: str | os.PathLike[str], chunks: list[bytes]) -> int:
    try:
        with atomic_write(path, "wb", durable=True) as f:
            for c in chunks:
                f.write(c)
    except OSError as e:
        raise DataFormatError(f"cannot write {path}: {e.strerror or e}") from e
    return sum(len(c) for c in chunks)


def _read_bytes(path: str | os.PathLike[str]) -> bytes:
    try:
        return Path(path).read_bytes()
    except OSError as e:
        raise DataFormatError(f"cannot read {path}: {e.strerror or e}") from e


_TOKEN = re.compile(rb"\s*(\S+)")
_UINT = re.compile(rb"\d+")


def _parse_header(data: bytes, magic: bytes, name: str) -> tuple[str, int, float, int]:
    """``AbstractOcTree::readHeader``: (id, size, res, offset of the binary data)."""
    nl = data.find(b"\n")
    first = data if nl < 0 else data[:nl]
    if not first.startswith(magic):
        what = "binary (.bt)" if magic == BT_HEADER else "full (.ot)"
        raise DataFormatError(f"{name}: not an OctoMap {what} file: first line "
                              f"{first[:60]!r} does not start with {magic.decode()!r}")
    pos = nl + 1
    tree_id, size, res = "", None, None

    def skip_line(p: int) -> int:
        e = data.find(b"\n", p)
        return len(data) if e < 0 else e + 1

    def next_token(p: int) -> tuple[bytes | None, int]:
        mt = _TOKEN.match(data, p)
        return (None, len(data)) if mt is None else (mt.group(1), mt.end())

    while True:
        tok, pos = next_token(pos)
        if tok is None:
            raise DataFormatError(f"{name}: header ends without a 'data' line (truncated file?)")
        if tok == b"data":
            pos = skip_line(pos)
            break
        if tok.startswith(b"#"):
            pos = skip_line(pos)
        elif tok == b"id":
            val, pos = next_token(pos)
            tree_id = (val or b"").decode("ascii", "replace")
        elif tok == b"size":
            val, pos = next_token(pos)
            if val is None or not _UINT.fullmatch(val):
                raise DataFormatError(f"{name}: bad 'size' in header: {val!r}")
            size = int(val)
        elif tok == b"res":
            val, pos = next_token(pos)
            try:
                res = float(val or b"")
            except ValueError:
                raise DataFormatError(f"{name}: bad 'res' in header: {val!r}") from None
        else:  # unknown keyword: OctoMap warns and skips the line
            pos = skip_line(pos)
    if not tree_id:
        raise DataFormatError(f"{name}: header has no tree id")
    if size is None:
        raise DataFormatError(f"{name}: header has no 'size'")
    if res is None or not (np.isfinite(res) and res > 0):
        raise DataFormatError(f"{name}: header resolution must be > 0, got {res!r}")
    if tree_id == "1":  # deprecated id, as OctoMap
        tree_id = "OcTree"
    return tree_id, size, res, pos


class _Malformed(Exception):
    pass


def _check_preorder(counts: np.ndarray) -> None:
    """The child counts must describe exactly one tree in pre-order (raises _Malformed)."""
    pending = 1 + np.cumsum(counts - 1)  # nodes still to read after each node
    ends = np.flatnonzero(pending == 0)
    if ends.size == 0:
        raise _Malformed(f"the node stream ends before the tree is complete "
                         f"({int(pending[-1])} more node(s) expected)")
    if ends[0] != len(counts) - 1:
        raise _Malformed(f"the tree is complete after {int(ends[0]) + 1} node records but the "
                         f"stream holds {len(counts)}")


def _preorder_links(counts: np.ndarray, max_height: int) -> tuple[np.ndarray, np.ndarray]:
    """Parent index and rank among its siblings of every node of a pre-order stream with per-node
    child counts, without a stack: contract nodes whose children are all leaves, one level per
    round (raises _Malformed when the tree is higher than ``max_height``)."""
    n = len(counts)
    parent = np.full(n, -1, dtype=np.int64)
    rank = np.zeros(n, dtype=np.int64)
    idx = np.arange(n)
    c = counts.astype(np.int64).copy()
    for _ in range(max_height + 1):
        if len(idx) == 1:
            return parent, rank
        leaf = c == 0
        nleaf = np.concatenate(([0], np.cumsum(leaf)))
        inner = np.flatnonzero(~leaf)
        ci = c[inner]
        end = np.minimum(inner + 1 + ci, len(idx))
        ready_sel = (inner + 1 + ci <= len(idx)) & (nleaf[end] - nleaf[inner + 1] == ci)
        ready, rc = inner[ready_sel], ci[ready_sel]
        if ready.size == 0:  # cannot happen after _check_preorder
            raise _Malformed("inconsistent child masks")
        rep = np.repeat(ready, rc)
        offs = np.arange(len(rep)) - np.repeat(np.cumsum(rc) - rc, rc)
        kids = rep + 1 + offs
        parent[idx[kids]] = idx[rep]
        rank[idx[kids]] = offs
        keep = np.ones(len(idx), dtype=bool)
        keep[kids] = False
        c[ready] = 0
        idx, c = idx[keep], c[keep]
    raise _Malformed(f"the tree is deeper than {TREE_DEPTH} levels")


def _depths_and_morton(parent: np.ndarray, child_idx: np.ndarray) -> tuple[np.ndarray,
                                                                           np.ndarray]:
    """Depth and first-corner Morton code of every node from parent links (parents first)."""
    n = len(parent)
    # depth by pointer jumping (the height is at most 16: 5 rounds)
    depth = (parent >= 0).astype(np.int64)
    nxt = parent.copy()
    while True:
        live = np.flatnonzero(nxt >= 0)
        if live.size == 0:
            break
        up = nxt[live]
        depth[live] += depth[up]
        nxt[live] = nxt[up]
    m = np.zeros(n, dtype=np.int64)
    for d, at in enumerate(_by_depth(depth)):
        if d > 0 and at.size:
            m[at] = m[parent[at]] | (child_idx[at] << (3 * (TREE_DEPTH - d)))
    return depth, m


def _by_depth(depth: np.ndarray) -> list[np.ndarray]:
    """Node indices (ascending) per depth 0..16."""
    order = np.argsort(depth, kind="stable")
    bounds = np.cumsum(np.bincount(depth, minlength=TREE_DEPTH + 1))
    return np.split(order, bounds[:TREE_DEPTH])


# --------------------------------------------------------------------------- .ot


PayloadFormat = DTypeLike | Mapping[str, DTypeLike] | None
"""A payload layout given by the caller: one dtype, or one per tree id."""


def _payload_format(tree_id: str, payload_format: PayloadFormat,
                    name: str | None) -> np.dtype | None:
    if tree_id in _BUILTIN:
        return _BUILTIN[tree_id]
    fmt: Any = (payload_format.get(tree_id) if isinstance(payload_format, Mapping)
                else payload_format)
    if fmt is None and tree_id in NODE_TYPES:
        fmt = NODE_TYPES.get(tree_id).record
        if fmt is None:
            return None
    if fmt is None:
        where = f"{name}: " if name else ""
        raise DataFormatError(f"{where}unknown tree id {tree_id!r} (known: "
                              f"{', '.join(NODE_TYPES.names())}; a plug-in's node type is known "
                              "once its module is imported, or pass payload_format)")
    dtype: np.dtype = np.dtype(fmt)
    return dtype


def _le(fmt: np.dtype) -> np.dtype:
    return fmt.newbyteorder("<")


def _record_dtype(fmt: np.dtype | None) -> np.dtype:
    if fmt is None:
        return np.dtype([("value", "<f4"), ("mask", "u1")])
    return np.dtype([("value", "<f4"), ("payload", _le(fmt)), ("mask", "u1")])


def _default_format(payload: np.ndarray) -> np.dtype:
    if payload.dtype.names is not None or payload.ndim == 1:
        return payload.dtype
    return np.dtype((payload.dtype, payload.shape[1:]))


def ot_bytes(tree: Tree, resolution: float, *, tree_id: str = "OcTree",
             payload_format: DTypeLike | None = None) -> bytes:
    """The bytes :func:`write_ot` writes."""
    _check_write_args(tree, resolution, tree_id)
    if tree_id == "OcTree":
        fmt = None
    elif tree_id == "ColorOcTree":
        # a system may write more under this id (SSMI's writeData), as OctoMap lets it
        fmt = COLOR_FORMAT if payload_format is None else np.dtype(payload_format)
    elif payload_format is not None:
        fmt = np.dtype(payload_format)
    elif tree_id in NODE_TYPES:
        fmt = NODE_TYPES.get(tree_id).record
    elif tree.payload is not None:
        fmt = _default_format(tree.payload)
    else:
        raise InvalidDataError(f"tree id {tree_id!r} needs a payload (the tree has none)")
    rec = np.zeros(tree.num_nodes, dtype=_record_dtype(fmt))
    rec["value"] = tree.value
    rec["mask"] = tree.child_mask
    if fmt is not None:
        if tree.payload is None:
            if tree_id != "ColorOcTree":
                raise InvalidDataError(f"tree id {tree_id!r} needs a payload")
            rec["payload"] = 255  # OctoMap's unset colour (white)
        else:
            try:
                rec["payload"] = tree.payload
            except (ValueError, TypeError) as e:
                raise InvalidDataError(f"payload of shape {tree.payload.shape} and dtype "
                                       f"{tree.payload.dtype} does not fit {fmt}: {e}") from e
    return _header(OT_HEADER, tree_id, tree.num_nodes, resolution) + rec.tobytes()


def write_ot(path: str | os.PathLike[str], tree: Tree, resolution: float, *,
             tree_id: str = "OcTree", payload_format: DTypeLike | None = None) -> int:
    """Write ``tree`` as an OctoMap ``.ot`` file (atomically); returns the byte size.

    ``tree_id`` "OcTree" writes the log-odds only, "ColorOcTree" log-odds + the (M, 3)
    ``uint8`` payload as r, g, b (white where the tree has no payload); any other name writes
    log-odds + ``tree.payload`` in ``payload_format`` (default: the payload's own dtype), as
    little-endian fixed-size records.
    """
    data = ot_bytes(tree, resolution, tree_id=tree_id, payload_format=payload_format)
    return _atomic_write(path, [data])


def parse_ot(data: bytes, *, name: str = "<bytes>",
             payload_format: DTypeLike | Mapping[str, DTypeLike] | None = None) -> OctreeFile:
    """Parse the bytes of an ``.ot`` file (see :func:`read_ot`)."""
    try:
        return _parse_ot(data, name, payload_format)
    except _Malformed as e:
        raise DataFormatError(f"{name}: corrupt octree data: {e}") from None
    except (ValueError, IndexError, OverflowError, TypeError) as e:
        raise DataFormatError(f"{name}: corrupt octree file: {e}") from None


def _parse_ot(data: bytes, name: str, payload_format: PayloadFormat) -> OctreeFile:
    tree_id, size, res, off = _parse_header(data, OT_HEADER, name)
    fmt = _payload_format(tree_id, payload_format, name)
    rd = _record_dtype(fmt)
    body = len(data) - off
    if size == 0:
        if body:
            raise DataFormatError(f"{name}: header says 0 nodes but {body} data bytes follow")
        empty_pay = None if fmt is None else np.zeros(0, dtype=_native(fmt))
        return OctreeFile(tree_id, res, Tree.empty(empty_pay))
    need = size * rd.itemsize
    if body < need:
        raise DataFormatError(f"{name}: truncated: header says {size} nodes "
                              f"({need} bytes of {rd.itemsize} B records), file has {body}")
    if body > need:
        raise DataFormatError(f"{name}: size mismatch: header says {size} nodes ({need} bytes) "
                              f"but {body} data bytes follow")
    rec = np.frombuffer(data, dtype=rd, count=size, offset=off)
    mask = rec["mask"].copy()
    counts = _POPCOUNT[mask]
    _check_preorder(counts)
    parent, rank = _preorder_links(counts, TREE_DEPTH)
    cidx = np.zeros(size, dtype=np.int64)
    nonroot = parent >= 0
    cidx[nonroot] = _NTH_BIT[mask[parent[nonroot]], rank[nonroot]]
    depth, m = _depths_and_morton(parent, cidx)
    value = rec["value"].astype(np.float32)
    payload = None
    if fmt is not None:
        payload = np.ascontiguousarray(rec["payload"]).astype(_native_base(fmt))
    return OctreeFile(tree_id, res, Tree(depth.astype(np.uint8), _codes_of_morton(m), mask,
                                           value, payload))


def _native(fmt: np.dtype) -> np.dtype:
    return fmt.newbyteorder("=")


def _native_base(fmt: np.dtype) -> np.dtype:
    """dtype of the array that ``rec['payload']`` becomes, in native byte order."""
    return (fmt.base if fmt.subdtype is not None else fmt).newbyteorder("=")


def read_ot(path: str | os.PathLike[str], *,
            payload_format: DTypeLike | Mapping[str, DTypeLike] | None = None) -> OctreeFile:
    """Read an ``.ot`` file: ``(tree_id, resolution, tree)``.

    "OcTree" files give no payload, "ColorOcTree" files an (M, 3) ``uint8`` r, g, b payload; any
    other tree id has the record of its registered node type
    (:data:`~evsmap.mapping.node_type.NODE_TYPES`), or ``payload_format`` (its payload dtype, or
    a mapping from tree id to dtype), which takes precedence.

    Raises:
        DataFormatError: missing, truncated or corrupt file, or an unknown tree id.
    """
    return parse_ot(_read_bytes(path), name=str(path), payload_format=payload_format)


# --------------------------------------------------------------------------- .bt


def to_max_likelihood(tree: Tree, *, occupancy_thres: float = DEFAULT_OCCUPANCY_THRES,
                      clamp_min: float = DEFAULT_CLAMP_MIN,
                      clamp_max: float = DEFAULT_CLAMP_MAX) -> Tree:
    """What ``writeBinary`` does to the live tree: ``toMaxLikelihood()`` then ``prune()``.
    Thresholds are probabilities, converted as OctoMap does (:func:`logodds`)."""
    thr, lo, hi = logodds(occupancy_thres), logodds(clamp_min), logodds(clamp_max)
    ml = np.where(tree.value >= thr, hi, lo).astype(np.float32)
    return tree.prune(ml, min_depth=1, stop_early=True)


def bt_bytes(tree: Tree, resolution: float, *, tree_id: str = "OcTree",
             occupancy_thres: float = DEFAULT_OCCUPANCY_THRES,
             clamp_min: float = DEFAULT_CLAMP_MIN, clamp_max: float = DEFAULT_CLAMP_MAX) -> bytes:
    """The bytes :func:`write_bt` writes."""
    _check_write_args(tree, resolution, tree_id)
    t = to_max_likelihood(tree, occupancy_thres=occupancy_thres, clamp_min=clamp_min,
                          clamp_max=clamp_max)
    head = _header(BT_HEADER, tree_id, t.num_nodes, resolution)
    if t.num_nodes == 0:
        return head
    thr = logodds(occupancy_thres)
    is_rec = t.child_mask != 0
    is_rec[0] = True  # writeBinaryData always writes the root
    rec_of = np.cumsum(is_rec) - 1
    parent = t.parents()
    cidx = t.child_index()
    nr = np.flatnonzero(parent >= 0)
    code = np.where(t.child_mask[nr] != 0, 3, np.where(t.value[nr] >= thr, 2, 1))
    slots = np.zeros((int(is_rec.sum()), 8), dtype=np.uint8)
    slots[rec_of[parent[nr]], cidx[nr]] = code
    shifts = np.array([0, 2, 4, 6], dtype=np.uint8)
    out = np.empty((len(slots), 2), dtype=np.uint8)
    out[:, 0] = np.bitwise_or.reduce(slots[:, :4] << shifts, axis=1)
    out[:, 1] = np.bitwise_or.reduce(slots[:, 4:] << shifts, axis=1)
    return head + out.tobytes()


def write_bt(path: str | os.PathLike[str], tree: Tree, resolution: float, *,
             tree_id: str = "OcTree", occupancy_thres: float = DEFAULT_OCCUPANCY_THRES,
             clamp_min: float = DEFAULT_CLAMP_MIN, clamp_max: float = DEFAULT_CLAMP_MAX) -> int:
    """Write ``tree`` as an OctoMap ``.bt`` file (atomically), as ``writeBinary`` does: maximum
    likelihood + prune first (``tree`` itself is not changed). Returns the byte size.
    ``occupancy_thres``, ``clamp_min``, ``clamp_max`` are probabilities (OctoMap defaults)."""
    data = bt_bytes(tree, resolution, tree_id=tree_id, occupancy_thres=occupancy_thres,
                    clamp_min=clamp_min, clamp_max=clamp_max)
    return _atomic_write(path, [data])


def parse_bt(data: bytes, *, name: str = "<bytes>", clamp_min: float = DEFAULT_CLAMP_MIN,
             clamp_max: float = DEFAULT_CLAMP_MAX) -> OctreeFile:
    """Parse the bytes of a ``.bt`` file (see :func:`read_bt`)."""
    try:
        return _parse_bt(data, name, logodds(clamp_min), logodds(clamp_max))
    except _Malformed as e:
        raise DataFormatError(f"{name}: corrupt binary octree data: {e}") from None
    except (ValueError, IndexError, OverflowError, TypeError) as e:
        raise DataFormatError(f"{name}: corrupt binary octree file: {e}") from None


def _parse_bt(data: bytes, name: str, lo: np.float32, hi: np.float32) -> OctreeFile:
    tree_id, size, res, off = _parse_header(data, BT_HEADER, name)
    body = len(data) - off
    if size == 0:
        if body:
            raise DataFormatError(f"{name}: header says 0 nodes but {body} data bytes follow")
        return OctreeFile(tree_id, res, Tree.empty())
    if body < 2:
        raise DataFormatError(f"{name}: truncated: no node data after the header")
    nrec = body // 2
    raw = np.frombuffer(data, dtype=np.uint8, count=2 * nrec, offset=off).reshape(nrec, 2)
    shifts = np.array([0, 2, 4, 6], dtype=np.uint8)
    codes = np.concatenate([(raw[:, :1] >> shifts) & 3, (raw[:, 1:] >> shifts) & 3], axis=1)
    inner_kids = codes == 3
    counts = inner_kids.sum(axis=1)
    pending = 1 + np.cumsum(counts - 1)
    ends = np.flatnonzero(pending == 0)
    if ends.size == 0:
        raise DataFormatError(f"{name}: truncated: the node stream ends before the tree is "
                              f"complete ({int(pending[-1])} more inner node(s) expected)")
    nrec = int(ends[0]) + 1
    if 2 * nrec != body:
        raise DataFormatError(f"{name}: the tree is complete after {2 * nrec} data bytes but "
                              f"{body} follow (trailing or corrupt data)")
    codes, inner_kids, counts = codes[:nrec], inner_kids[:nrec], counts[:nrec]
    imask = np.bitwise_or.reduce(inner_kids.astype(np.uint8) << np.arange(8, dtype=np.uint8),
                                 axis=1)
    parent, rank = _preorder_links(counts, TREE_DEPTH - 1)
    cidx = np.zeros(nrec, dtype=np.int64)
    nonroot = parent >= 0
    cidx[nonroot] = _NTH_BIT[imask[parent[nonroot]], rank[nonroot]]
    rdepth, rm = _depths_and_morton(parent, cidx)

    empty_inner = np.flatnonzero((codes == 0).all(axis=1) & nonroot)
    if empty_inner.size:
        raise DataFormatError(f"{name}: corrupt binary octree data: inner node record "
                              f"{int(empty_inner[0])} has no children")
    r_leaf, s_leaf = np.nonzero((codes == 1) | (codes == 2))
    n_nodes = nrec + len(r_leaf)
    if n_nodes != size:
        raise DataFormatError(f"{name}: size mismatch: header says {size} nodes, the data holds "
                              f"{n_nodes}")
    ldepth = rdepth[r_leaf] + 1
    lm = rm[r_leaf] | (s_leaf.astype(np.int64) << (3 * (TREE_DEPTH - ldepth)))
    lval = np.where(codes[r_leaf, s_leaf] == 2, hi, lo).astype(np.float32)

    # inner values: max of the children, bottom-up; the root keeps clamping max (as OctoMap)
    rval = np.full(nrec, -np.inf, dtype=np.float32)
    np.maximum.at(rval, r_leaf, lval)
    for d in range(TREE_DEPTH - 1, 0, -1):
        at = np.flatnonzero(rdepth == d)
        if at.size:
            np.maximum.at(rval, parent[at], rval[at])
    rval[0] = hi

    rmask = np.bitwise_or.reduce((codes != 0).astype(np.uint8) << np.arange(8, dtype=np.uint8),
                                 axis=1)
    depth = np.concatenate([rdepth, ldepth])
    m = np.concatenate([rm, lm])
    order = np.lexsort((depth, m))
    tree = Tree(depth[order].astype(np.uint8), _codes_of_morton(m[order]),
                np.concatenate([rmask, np.zeros(len(lm), np.uint8)])[order],
                np.concatenate([rval, lval])[order])
    return OctreeFile(tree_id, res, tree)


def read_bt(path: str | os.PathLike[str], *, clamp_min: float = DEFAULT_CLAMP_MIN,
            clamp_max: float = DEFAULT_CLAMP_MAX) -> OctreeFile:
    """Read a ``.bt`` file: ``(tree_id, resolution, tree)`` as ``readBinary`` rebuilds it
    (leaves at the clamping log-odds, inner nodes the max of their children, the root at the
    clamping max).

    Raises:
        DataFormatError: missing, truncated or corrupt file, or a size mismatch.
    """
    return parse_bt(_read_bytes(path), name=str(path), clamp_min=clamp_min, clamp_max=clamp_max)

