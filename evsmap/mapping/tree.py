"""Canonical pruned octree built from finest-level leaves, vectorised with numpy.

A :class:`Tree` holds every node of an OctoMap-style octree (inner nodes and leaves, the root at
depth 0 down to the finest voxels at depth 16) as flat arrays in OctoMap's depth-first pre-order:
a node, then the subtrees of its children in child-index order 0..7 (child index = x bit +
2 * y bit + 4 * z bit, see :mod:`evsmap.mapping.keys`). Sorting nodes by (Morton code of their
first corner, depth) gives exactly this order, which is also the order of OctoMap's ``.ot`` and
``.bt`` streams and of its ``tree_iterator``.

:func:`build_tree` reproduces what OctoMap's incremental updates converge to:

* an inner node's value is the maximum of its children's values
  (``OcTreeNode::updateOccupancyChildren`` / ``getMaxChildLogOdds``);
* a node whose 8 children all exist, are leaves and are exactly equal (``==`` on the value and on
  every further "equal column") becomes a leaf carrying child 0's data
  (``OcTreeBaseImpl::isNodeCollapsible`` / ``pruneNode``), applied bottom-up so uniform regions
  collapse over several levels.

All work is per tree level (17 levels at most); nothing loops per node or voxel in Python.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from evsmap.errors import InvalidDataError
from evsmap.mapping.keys import TREE_DEPTH, morton, unpack

__all__ = [
    "Tree",
    "build_tree",
    "build_color_tree",
    "expand_leaves",
    "octomap_colour_average",
    "octomap_colour_prune",
    "unmorton",
]

#: ``Aggregator(child_payload, group, n_groups) -> (n_groups, ...)``: ``child_payload`` holds the
#: payload rows of the children of ``n_groups`` parents, ``group`` (sorted, int64) the parent
#: index of every child row, children of one parent in child-index order.
Aggregator = Callable[[np.ndarray, np.ndarray, int], np.ndarray]

_M48 = (1 << 48) - 1
DEFAULT_MAX_VOXELS = 50_000_000


def _compact(m: np.ndarray, axis: int) -> np.ndarray:
    """Bits ``3 i + axis`` of int64 Morton codes -> bit i (inverse of the spreading in
    :func:`evsmap.mapping.keys.morton`), int64."""
    v = m >> axis if axis else m.copy()
    v &= 0x249249249249
    for sh, mask in ((2, 0x0C30C30C30C3), (4, 0x00F00F00F00F), (8, 0x0000FF0000FF),
                     (16, 0xFFFF)):
        v |= v >> sh
        v &= mask
    return v


def unmorton(m: np.ndarray) -> np.ndarray:
    """Inverse of :func:`evsmap.mapping.keys.morton`: ``int64`` (N, 3) keys."""
    m = np.asarray(m).astype(np.int64)
    return np.stack([_compact(m, 0), _compact(m, 1), _compact(m, 2)], axis=1)


def _morton_of_codes(codes: np.ndarray) -> np.ndarray:
    return morton(unpack(codes)).astype(np.int64)


def _codes_of_morton(m: np.ndarray) -> np.ndarray:
    m = np.asarray(m, dtype=np.int64)
    code = _compact(m, 0)
    code <<= 32
    code |= _compact(m, 1) << 16
    code |= _compact(m, 2)
    return code


def _shift(depth: np.ndarray | int) -> np.ndarray | int:
    """Number of Morton bits below a node at ``depth`` (3 per level under it)."""
    return 3 * (TREE_DEPTH - np.asarray(depth, dtype=np.int64))


def _rows_equal(col: np.ndarray, ref: np.ndarray) -> np.ndarray:
    eq: np.ndarray = np.asarray(col == ref)
    if eq.ndim > 1:
        eq = np.asarray(eq.reshape(eq.shape[0], -1).all(axis=1))
    return eq


# --------------------------------------------------------------------------- colour helpers

_WHITE = 255


def octomap_colour_average(child_payload: np.ndarray, group: np.ndarray, n_groups: int
                           ) -> np.ndarray:
    """OctoMap's ``ColorOcTreeNode::getAverageChildColor`` per parent: the integer mean (truncated)
    of the children whose colour is set (not white 255,255,255); white when none is set.

    ``child_payload`` is (N, 3) ``uint8`` r, g, b.
    """
    c = np.asarray(child_payload).reshape(len(child_payload), 3).astype(np.int64)
    is_set = (c != _WHITE).any(axis=1)
    cnt = np.bincount(group, weights=is_set, minlength=n_groups).astype(np.int64)
    out = np.full((n_groups, 3), _WHITE, dtype=np.int64)
    has = cnt > 0
    for ch in range(3):  # r, g, b
        s = np.bincount(group, weights=c[:, ch] * is_set, minlength=n_groups).astype(np.int64)
        out[has, ch] = s[has] // cnt[has]
    return out.astype(np.uint8)


def octomap_colour_prune(child_payload: np.ndarray, group: np.ndarray, n_groups: int
                         ) -> np.ndarray:
    """Colour of a pruned node as ``ColorOcTree::pruneNode`` sets it: child 0's colour, replaced by
    the average child colour when child 0's colour is set."""
    c = np.asarray(child_payload).reshape(len(child_payload), 3)
    first = np.flatnonzero(np.r_[True, group[1:] != group[:-1]])
    out = c[first].astype(np.uint8)
    avg = octomap_colour_average(c, group, n_groups)
    first_set = (out != _WHITE).any(axis=1)
    out[first_set] = avg[first_set]
    return out


# --------------------------------------------------------------------------- the tree


@dataclass(frozen=True, eq=False)
class Tree:
    """All nodes of an octree as flat arrays in OctoMap's depth-first pre-order.

    Attributes:
        depth: ``uint8`` (M,) tree depth, 0 = root, 16 = finest voxels.
        code: ``int64`` (M,) packed key (:func:`evsmap.mapping.keys.pack`) of the node's first
            corner (the low ``16 - depth`` bits of each key are zero).
        child_mask: ``uint8`` (M,) bit i set = child i exists; 0 = leaf.
        value: ``float32`` (M,) log-odds (inner nodes: the max of their children).
        payload: per-node payload rows (structured (M,) or (M, k)), or None.
    """

    depth: np.ndarray
    code: np.ndarray
    child_mask: np.ndarray
    value: np.ndarray
    payload: np.ndarray | None = None

    # ---- sizes
    @property
    def num_nodes(self) -> int:
        """Number of nodes, OctoMap's ``size()``."""
        return int(len(self.depth))

    @property
    def is_leaf(self) -> np.ndarray:
        return np.asarray(self.child_mask == 0)

    @property
    def num_leaves(self) -> int:
        """OctoMap's ``getNumLeafNodes()``."""
        return int(np.count_nonzero(self.child_mask == 0))

    @property
    def num_inner(self) -> int:
        return self.num_nodes - self.num_leaves

    @property
    def keys(self) -> np.ndarray:
        """``int64`` (M, 3) first-corner keys."""
        return unpack(self.code)

    @property
    def morton(self) -> np.ndarray:
        """``int64`` (M,) Morton codes of the first corners; pre-order sorts by (morton, depth)."""
        return _morton_of_codes(self.code)

    def memory_bytes(self, node_bytes: int = 16, children_array_bytes: int = 64,
                     base_bytes: int = 0) -> int:
        """OctoMap's ``memoryUsage()``: ``base + node_bytes * size + children_array_bytes *
        (size - leaves)`` (``OcTreeBaseImpl::memoryUsage``: ``sizeof(OcTreeBaseImpl) +
        memoryUsageNode() * tree_size + num_inner_nodes * sizeof(NODE*[8])``). With octomap-python
        1.10 on x86-64, ``sizeof(NODE)`` is 16 for OcTree and ColorOcTree nodes and
        ``sizeof(OcTreeBaseImpl)`` is 320 (pass ``base_bytes=320`` to match it exactly)."""
        return int(base_bytes + node_bytes * self.num_nodes
                   + children_array_bytes * self.num_inner)

    @classmethod
    def empty(cls, payload: np.ndarray | None = None) -> Tree:
        """A tree without nodes (no root); ``payload`` gives the payload dtype/row shape."""
        pay = None if payload is None else np.asarray(payload)[:0].copy()
        return cls(np.zeros(0, np.uint8), np.zeros(0, np.int64), np.zeros(0, np.uint8),
                   np.zeros(0, np.float32), pay)

    # ---- structure
    def parents(self) -> np.ndarray:
        """``int64`` (M,) index of each node's parent (-1 for the root)."""
        depth = self.depth.astype(np.int64)
        parent = np.full(len(depth), -1, dtype=np.int64)
        order = np.argsort(depth, kind="stable")
        bounds = np.cumsum(np.bincount(depth, minlength=TREE_DEPTH + 1))
        levels = np.split(order, bounds[:TREE_DEPTH])
        for d in range(1, TREE_DEPTH + 1):
            idx, up = levels[d], levels[d - 1]
            if idx.size == 0:
                break
            parent[idx] = up[np.searchsorted(up, idx) - 1]
        return parent

    def child_index(self) -> np.ndarray:
        """``int64`` (M,) index 0..7 of each node in its parent (0 for the root)."""
        depth = self.depth.astype(np.int64)
        m = self.morton
        ci = (m >> np.maximum(_shift(depth), 0)) & 7
        ci[depth == 0] = 0
        return ci

    def identical(self, other: Tree) -> bool:
        """Same nodes, values (bitwise) and payloads."""
        same = (np.array_equal(self.depth, other.depth)
                and np.array_equal(self.code, other.code)
                and np.array_equal(self.child_mask, other.child_mask)
                and np.array_equal(self.value.view(np.uint32), other.value.view(np.uint32)))
        if not same or (self.payload is None) != (other.payload is None):
            return False
        return (self.payload is None or other.payload is None
                or np.array_equal(self.payload, other.payload))

    def leaves(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
        """(depth, code, value, payload) of the leaves, in pre-order."""
        leaf = self.child_mask == 0
        pay = None if self.payload is None else self.payload[leaf]
        return self.depth[leaf], self.code[leaf], self.value[leaf], pay

    def expand(self, max_voxels: int = DEFAULT_MAX_VOXELS
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """Leaves at the finest level: ``(codes, values, payload)`` in Morton order, a pruned leaf
        at depth d expanded to all ``8 ** (16 - d)`` voxels it covers.

        Raises:
            InvalidDataError: the expansion would exceed ``max_voxels`` voxels.
        """
        d, c, v, p = self.leaves()
        return expand_leaves(d, c, v, p, max_voxels=max_voxels)

    def prune(self, values: np.ndarray | None = None, *, min_depth: int = 0,
              stop_early: bool = False) -> Tree:
        """Prune this tree the way ``OcTreeBaseImpl::prune`` does, comparing ``values`` (default:
        the tree's values): for depth 15 down to ``min_depth``, every node whose 8 children exist,
        are leaves and have equal values becomes a leaf with child 0's value and payload.

        OctoMap's ``prune()`` is ``min_depth=1, stop_early=True`` (the root is never pruned and
        the pass stops at the first level that pruned nothing); ``writeBinary`` uses it after
        ``toMaxLikelihood``.
        """
        val = np.array(self.value if values is None else values, dtype=np.float32)
        if val.shape != self.value.shape:
            raise InvalidDataError(f"values must have shape {self.value.shape}, got {val.shape}")
        mask = self.child_mask.copy()
        depth = self.depth.astype(np.int64)
        n = len(depth)
        keep = np.ones(n, dtype=bool)
        parent = self.parents()
        payload = None if self.payload is None else self.payload.copy()
        for d in range(TREE_DEPTH - 1, min_depth - 1, -1):
            ch = np.flatnonzero((depth == d + 1) & keep)
            p = parent[ch]
            # the first child of an inner node directly follows it in pre-order
            bad_child = (mask[ch] != 0) | (val[ch] != val[p + 1])
            bad = np.zeros(n, dtype=bool)
            bad[p[bad_child]] = True
            coll = np.flatnonzero((depth == d) & keep & (mask == 0xFF) & ~bad)
            if coll.size == 0:
                if stop_early:
                    break
                continue
            val[coll] = val[coll + 1]
            if payload is not None:
                payload[coll] = payload[coll + 1]
            mask[coll] = 0
            gone = np.zeros(n, dtype=bool)
            gone[coll] = True
            keep[ch[gone[p]]] = False
        return Tree(self.depth[keep], self.code[keep], mask[keep], val[keep],
                    None if payload is None else payload[keep])

    @classmethod
    def from_nodes(cls, depth: np.ndarray, code: np.ndarray, value: np.ndarray,
                   payload: np.ndarray | None = None) -> Tree:
        """A tree from an unordered set of nodes (every node's ancestors must be included): sorts
        them into pre-order and derives the child masks."""
        depth = np.asarray(depth, dtype=np.int64)
        code = np.asarray(code, dtype=np.int64)
        m = _morton_of_codes(code)
        order = np.lexsort((depth, m))
        depth, code, m = depth[order], code[order], m[order]
        value = np.asarray(value, dtype=np.float32)[order]
        payload = None if payload is None else np.asarray(payload)[order]
        mask = np.zeros(len(depth), dtype=np.uint8)
        tree = cls(depth.astype(np.uint8), code, mask, value, payload)
        par = tree.parents()
        nonroot = np.flatnonzero(par >= 0)
        ci = (m[nonroot] >> _shift(depth[nonroot])) & 7
        np.bitwise_or.at(mask, par[nonroot], (1 << ci).astype(np.uint8))
        return tree


# --------------------------------------------------------------------------- building


def expand_leaves(depth: np.ndarray, codes: np.ndarray, values: np.ndarray,
                  payload: np.ndarray | None = None, *, max_voxels: int = DEFAULT_MAX_VOXELS
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Expand leaves at any depth to the finest voxels they cover (Morton order per leaf, leaves
    in the given order): returns ``(codes, values, payload)``."""
    depth = np.asarray(depth, dtype=np.int64)
    codes = np.asarray(codes, dtype=np.int64)
    values = np.asarray(values, dtype=np.float32)
    if depth.size and (depth.min() < 0 or depth.max() > TREE_DEPTH):
        raise InvalidDataError("leaf depths must lie in 0..16")
    counts = np.left_shift(np.int64(1), _shift(depth))  # 8 ** (16 - d)
    if float(counts.astype(np.float64).sum()) > max_voxels:
        raise InvalidDataError(f"expanding {len(depth)} leaves gives more than {max_voxels} "
                               "finest voxels")
    total = int(counts.sum())
    m = _morton_of_codes(codes)
    starts = np.cumsum(counts) - counts
    rep = np.repeat(np.arange(len(depth)), counts)
    fine = m[rep] + (np.arange(total, dtype=np.int64) - starts[rep])
    pay = None if payload is None else np.asarray(payload)[rep]
    return _codes_of_morton(fine), values[rep], pay


def _as_column(rows: ArrayLike, n: int, name: str) -> np.ndarray:
    a = np.asarray(rows)
    if a.ndim == 0 or a.shape[0] != n:
        raise InvalidDataError(f"{name} must have {n} rows, got shape {a.shape}")
    return a


def build_tree(codes: np.ndarray, values: np.ndarray, *, payload: np.ndarray | None = None,
               equal_columns: Sequence[np.ndarray] | None = None,
               inner_value: np.ufunc = np.maximum,
               inner_payload: Aggregator | None = None,
               prune_payload: str | Aggregator = "first") -> Tree:
    """Canonical pruned octree from unique finest-level leaves.

    Args:
        codes: ``int64`` (N,) packed keys of the finest voxels (unique).
        values: ``float32`` (N,) log-odds per voxel.
        payload: optional per-voxel payload rows (structured (N,) or (N, k)).
        equal_columns: arrays (N rows) that must be exactly equal (``==``) among 8 sibling leaves
            for them to be pruned; default ``[values]``. Pass e.g. ``[values, semantics]`` to block
            pruning on differing semantics (or ``[values, payload]``).
        inner_value: ufunc whose ``reduceat`` aggregates children values for inner nodes
            (default ``np.maximum``, OctoMap's ``updateOccupancyChildren``).
        inner_payload: aggregator of children payloads for inner nodes (see :data:`Aggregator`);
            default None leaves inner payload rows zero.
        prune_payload: payload of a pruned node: ``"first"`` (child 0's, OctoMap's ``copyData``),
            ``"inner"`` (``inner_payload``'s aggregate) or an aggregator of its own.

    Returns:
        The tree in pre-order; empty (no root) when ``codes`` is empty.
    """
    codes, values, payload, eq_cols = _checked_leaves(codes, values, payload, equal_columns,
                                                      inner_payload, prune_payload)
    if len(codes) == 0:
        return Tree.empty(payload)
    level = _finest_level(codes, values, payload, eq_cols)
    nodes = _Nodes()
    for d in range(TREE_DEPTH, 0, -1):
        keep, parents = _parent_level(level, d, inner_value, inner_payload, prune_payload)
        nodes.add(level, keep, d)
        level = parents
    nodes.add(level, np.ones(len(level.m), dtype=bool), 0)  # the root
    return nodes.tree(with_payload=payload is not None)


def _checked_leaves(codes: np.ndarray, values: np.ndarray, payload: np.ndarray | None,
                    equal_columns: Sequence[np.ndarray] | None,
                    inner_payload: Aggregator | None, prune_payload: str | Aggregator
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, list[np.ndarray]]:
    """:func:`build_tree`'s arguments checked: ``(codes, values, payload, equal columns)``."""
    codes = np.asarray(codes)
    if codes.ndim != 1:
        raise InvalidDataError(f"codes must be 1-D, got shape {codes.shape}")
    codes = codes.astype(np.int64, copy=False)
    n = len(codes)
    values = _as_column(values, n, "values").astype(np.float32, copy=False)
    if values.ndim != 1:
        raise InvalidDataError(f"values must be 1-D, got shape {values.shape}")
    if payload is not None:
        payload = _as_column(payload, n, "payload")
    eq_cols = [values] if equal_columns is None else [
        _as_column(c, n, f"equal_columns[{i}]") for i, c in enumerate(equal_columns)]
    if prune_payload == "inner" and inner_payload is None:
        raise InvalidDataError("prune_payload='inner' needs an inner_payload aggregator")
    if not (callable(prune_payload) or prune_payload in ("first", "inner")):
        raise InvalidDataError(f"prune_payload must be 'first', 'inner' or a callable, "
                               f"got {prune_payload!r}")
    return codes, values, payload, eq_cols


@dataclass
class _Level:
    """The nodes of one depth while :func:`build_tree` climbs, in Morton order: Morton codes of
    their first corners, values, payload rows, equal columns, which are leaves, child masks."""

    m: np.ndarray
    val: np.ndarray
    pay: np.ndarray | None
    eqs: list[np.ndarray]
    leaf: np.ndarray
    mask: np.ndarray


def _finest_level(codes: np.ndarray, values: np.ndarray, payload: np.ndarray | None,
                  eq_cols: list[np.ndarray]) -> _Level:
    """The (non-empty) leaves as the deepest level, sorted by Morton code."""
    if codes.min() < 0 or codes.max() > _M48:
        raise InvalidDataError("codes must be packed 16-bit keys (0 <= code < 2**48)")
    m = _morton_of_codes(codes)
    order = np.argsort(m, kind="stable")
    m = m[order]
    if np.any(m[1:] == m[:-1]):
        raise InvalidDataError("codes must be unique")
    n = len(codes)
    return _Level(m, values[order], None if payload is None else payload[order],
                  [c[order] for c in eq_cols], np.ones(n, dtype=bool),
                  np.zeros(n, dtype=np.uint8))


def _parent_level(level: _Level, d: int, inner_value: np.ufunc,
                  inner_payload: Aggregator | None, prune_payload: str | Aggregator
                  ) -> tuple[np.ndarray, _Level]:
    """The parents (depth ``d - 1``) of the nodes of depth ``d``, 8 equal leaf children pruned
    into their parent: (which nodes of ``level`` stay in the tree, the parents' level)."""
    m, val, pay = level.m, level.val, level.pay
    sh = 3 * (TREE_DEPTH - d)
    pm = (m >> (sh + 3)) << (sh + 3)
    cidx = (m >> sh) & 7
    new = np.r_[True, pm[1:] != pm[:-1]]
    starts = np.flatnonzero(new)
    group = np.cumsum(new) - 1
    counts = np.diff(np.r_[starts, len(m)])

    pmask = np.bitwise_or.reduceat((1 << cidx).astype(np.uint8), starts)
    pval = inner_value.reduceat(val, starts).astype(np.float32)
    ok = level.leaf.copy()
    for col in level.eqs:
        ok &= _rows_equal(col, col[starts][group])
    coll = (counts == 8) & np.logical_and.reduceat(ok, starts)
    pval[coll] = val[starts[coll]]
    ppay = None if pay is None else _parent_payload(pay, group, starts, coll, inner_payload,
                                                    prune_payload)
    parents = _Level(pm[starts], pval, ppay, [col[starts] for col in level.eqs], coll,
                     np.where(coll, np.uint8(0), pmask).astype(np.uint8))
    return ~coll[group], parents


def _parent_payload(pay: np.ndarray, group: np.ndarray, starts: np.ndarray, coll: np.ndarray,
                    inner_payload: Aggregator | None, prune_payload: str | Aggregator
                    ) -> np.ndarray:
    """The parents' payload rows: ``inner_payload``'s aggregate (zero without one), a pruned
    parent's as ``prune_payload`` says."""
    ng = len(starts)
    if inner_payload is not None:
        ppay = np.asarray(inner_payload(pay, group, ng)).astype(pay.dtype, copy=False)
    else:
        ppay = np.zeros((ng,) + pay.shape[1:], dtype=pay.dtype)
    if coll.any():
        if prune_payload == "first":
            ppay[coll] = pay[starts[coll]]
        elif callable(prune_payload):
            ppay[coll] = np.asarray(prune_payload(pay, group, ng))[coll]
        # "inner": the aggregate already in ppay
    return ppay


class _Nodes:
    """The nodes that stay in the tree, collected level by level."""

    def __init__(self) -> None:
        self.m: list[np.ndarray] = []
        self.depth: list[np.ndarray] = []
        self.mask: list[np.ndarray] = []
        self.val: list[np.ndarray] = []
        self.pay: list[np.ndarray] = []

    def add(self, level: _Level, keep: np.ndarray, d: int) -> None:
        """The nodes of ``level`` (depth ``d``) where ``keep``."""
        self.m.append(level.m[keep])
        self.depth.append(np.full(int(keep.sum()), d, dtype=np.uint8))
        self.mask.append(level.mask[keep])
        self.val.append(level.val[keep])
        if level.pay is not None:
            self.pay.append(level.pay[keep])

    def tree(self, *, with_payload: bool) -> Tree:
        """The collected nodes in pre-order."""
        all_m = np.concatenate(self.m)
        all_d = np.concatenate(self.depth)
        order = np.lexsort((all_d, all_m))
        return Tree(all_d[order], _codes_of_morton(all_m[order]),
                    np.concatenate(self.mask)[order], np.concatenate(self.val)[order],
                    np.concatenate(self.pay)[order] if with_payload else None)


def build_color_tree(codes: np.ndarray, values: np.ndarray, colours: np.ndarray) -> Tree:
    """A tree as OctoMap's ``ColorOcTree`` holds it after ``updateInnerOccupancy()``: pruning on
    the occupancy only, inner colours the average of the children's set colours, a pruned node's
    colour as ``ColorOcTree::pruneNode`` sets it. ``colours``: (N, 3) ``uint8`` r, g, b."""
    colours = np.asarray(colours)
    if colours.ndim != 2 or colours.shape[1] != 3:
        raise InvalidDataError(f"colours must be (N, 3), got shape {colours.shape}")
    return build_tree(codes, values, payload=colours.astype(np.uint8),
                      inner_payload=octomap_colour_average, prune_payload=octomap_colour_prune)
