"""The leaf-array storage of evsmap's octree map updaters: frame -> scan -> occupancy update,
per-leaf payloads, the pruned tree built from the leaves.

An updater keeps its map as OctoMap's tree expanded to the finest level
(:class:`~evsmap.mapping.occupancy.OccupancyMap`: sorted leaf codes, log-odds and named payload
arrays). The pruned tree, which OctoMap keeps in memory and writes to its files, is built from the
leaves when it is needed (:meth:`OctreeUpdater.tree`): the two hold the same information because
OctoMap only prunes 8 identical children and expands them again before changing one. What is the
same for every storage - options, files, restore, queries - is the tree-level base
:class:`~evsmap.updaters.tree_map.OctreeMap`, whose other storage is a compared system's node
pool (``baselines.semantic_slam``).

As OctoMap splits a tree kind into its node class and its tree class, a kind of map is a
:class:`~evsmap.mapping.node_type.NodeType` (the node: payload columns, ``.ot`` record and codec,
pruning predicate, bytes per node, label and colour) and a subclass of :class:`OctreeUpdater`
(the tree: its options and its rules as typed methods - :meth:`~OctreeUpdater.update_payload`,
:meth:`~OctreeUpdater.inner_payload`, :meth:`~OctreeUpdater.pruned_payload`,
:meth:`~OctreeUpdater.prune_columns`, :meth:`~OctreeUpdater.inner_occupancy` and the files'
``published_file`` / ``message_file`` / ``colour_file``); ``docs/plugins.md``."""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from os import PathLike

import numpy as np

from evsmap.data import Frame, SemanticObservation
from evsmap.errors import DataFormatError, InvalidDataError
from evsmap.mapping.front_end import DirectScan, FramePoints, GroupedHits, compact
from evsmap.mapping.occupancy import OccupancyMap
from evsmap.mapping.raycast import scan_keys
from evsmap.mapping.tree import Tree
from evsmap.updaters.tree_map import (
    OCTOMAP_BASE_BYTES,
    FrontEndCounts,
    OctreeMap,
    check_observation,
    point_codes,
)

__all__ = ["OCTOMAP_BASE_BYTES", "FramePoints", "OctreeUpdater", "check_observation", "compact",
           "point_codes", "strongest_child"]


class OctreeUpdater(OctreeMap):
    """An octree map updater on leaf arrays: OctoMap occupancy plus the payload of its node type
    (options: :class:`~evsmap.updaters.tree_map.OctreeMap`).

    A subclass sets :attr:`node_type`, adds its options and overrides the rules its tree has;
    the defaults are OctoMap's ``OcTree`` (no payload update, zero inner records, a pruned node
    keeps child 0's record, pruning on the node type's ``prune_on``). A plug-in whose node has no
    rules can also pass ``node_type`` to a plain ``OctreeUpdater``.
    """

    has_leaf_map = True

    def init_storage(self) -> None:
        self.map = OccupancyMap(self.resolution, self.params)
        self._reusing = False
        self._reused_tree: Tree | None = None
        self._init_payloads()

    def leaves(self) -> OccupancyMap:
        return self.map

    # -- the node type's columns on this map -----------------------------------------------
    def _init_payloads(self) -> None:
        """Add the node type's payload columns to the (empty) leaf map."""
        for c in self.node_type.columns:
            self.map.add_payload(c.name, np.dtype(c.dtype), c.shape, fill=c.fill)

    def _columns(self) -> dict[str, np.ndarray]:
        return {n: self.map.payload(n) for n in self.node_type.column_names}

    def _payload_record(self) -> np.ndarray | None:
        """The leaves' payload as ``.ot`` records (None for a type without a record)."""
        return self.node_type.to_record(self._columns(), self.map.num_leaves)

    def _set_payload_record(self, record: np.ndarray | None) -> None:
        """Inverse of :meth:`_payload_record`: fill the payload columns from file records."""
        if record is None:
            return
        for name, values in self.node_type.from_record(record).items():
            self.map.payload(name)[:] = values

    # -- one frame: the direct front end ----------------------------------------------------
    def update_frame(self, frame: Frame, observation: SemanticObservation | None
                     ) -> FrontEndCounts:
        """The direct front end (:class:`~evsmap.mapping.front_end.FramePoints`), OctoMap's
        occupancy update of its rays, then :meth:`update_payload`."""
        points = FramePoints(frame, self.resolution, self.max_range, self.discretize,
                             self.kernels)
        # the rays are already discretized (once, in FramePoints) when that option is on
        keys = scan_keys(points.rays, points.origin, self.resolution,
                         max_range=self.max_range, discretize=False, kernels=self.kernels)
        update = self.map.apply(keys.free, keys.occupied)
        self.update_payload(DirectScan(frame, points, update, observation))
        return FrontEndCounts(centroids=len(points.voxel_codes), hits=len(keys.occupied),
                              rays=len(points.rays))

    def update_payload(self, scan: DirectScan) -> None:
        """How a frame changes the payload columns, after OctoMap's occupancy update (the
        node's ``updateNode``); none for an ``OcTree``."""

    def endpoint_voxels(self, points: FramePoints) -> GroupedHits:
        """The frame's hits grouped by voxel: (flat pixel index of every point that ends inside
        the range, the map indices of the distinct hit voxels, and each point's position among
        them)."""
        sel = np.flatnonzero(points.endpoint)
        used, local = compact(points.point_voxel[sel], len(points.voxel_codes))
        voxels, found = self.map.index(points.voxel_codes[used])
        if not np.all(found):  # cannot happen: every end point voxel was just inserted
            raise RuntimeError("end point voxel missing from the map")
        return GroupedHits(points.pixels[sel], voxels, local)

    # -- the tree: its rules ----------------------------------------------------------------
    def inner_payload(self, children: np.ndarray, group: np.ndarray,
                      n_groups: int) -> np.ndarray:
        """An inner node's record from its children's (``group``: the parent of every child
        row, sorted, children of a parent in child order; see
        :data:`evsmap.mapping.tree.Aggregator`); zero records by default."""
        return np.zeros((n_groups,) + children.shape[1:], dtype=children.dtype)

    def pruned_payload(self, children: np.ndarray, group: np.ndarray,
                       n_groups: int) -> np.ndarray:
        """A pruned node's record from its 8 children's: child 0's by default (OctoMap's
        ``copyData``)."""
        return children[np.flatnonzero(np.r_[True, group[1:] != group[:-1]])]

    def prune_columns(self) -> list[np.ndarray]:
        """The arrays that must be identical for 8 children to be pruned: the log-odds and the
        node type's ``prune_on`` columns."""
        return [self.map.logodds] + [self.map.payload(n) for n in self.node_type.prune_on]

    def inner_occupancy(self, tree: Tree) -> Tree:
        """The tree with its inner nodes' occupancy as the node's tree sets it; OctoMap's max of
        the children (as built) by default."""
        return tree

    @contextlib.contextmanager
    def reuse_tree(self) -> Iterator[None]:
        """Within the block, :meth:`tree` is built once (the map must not change inside)."""
        self._reused_tree = None
        self._reusing = True
        try:
            yield
        finally:
            self._reusing = False
            self._reused_tree = None

    def tree(self) -> Tree:
        """The pruned octree of the current map (built once inside :meth:`reuse_tree`)."""
        if self._reusing:
            if self._reused_tree is None:
                self._reused_tree = self._build_tree()
            return self._reused_tree
        return self._build_tree()

    def _build_tree(self) -> Tree:
        from evsmap.mapping.tree import build_tree

        tree = build_tree(self.map.codes, np.asarray(self.map.logodds),
                          payload=self._payload_record(), equal_columns=self.prune_columns(),
                          inner_payload=self.inner_payload, prune_payload=self.pruned_payload)
        return self.inner_occupancy(tree)

    def load_tree(self, tree: Tree, path: str | PathLike[str]) -> None:
        """The read tree's leaves expanded to the finest level, with their payloads."""
        try:
            codes, values, payload = tree.expand()
        except InvalidDataError as exc:  # coarse leaves covering too many voxels
            raise DataFormatError(f"{path}: {exc}") from None
        order = np.argsort(codes, kind="stable")
        self.map = OccupancyMap.from_leaves(self.resolution, codes[order], values[order],
                                            params=self.params)
        self._init_payloads()
        self._set_payload_record(None if payload is None else payload[order])

    def memory_nbytes(self) -> int:
        """Bytes of the leaf arrays: codes, log-odds and every payload."""
        m = self.map
        arrays = [m.codes, m.logodds] + [m.payload(n) for n in m.payload_names]
        return int(sum(a.nbytes for a in arrays))


def strongest_child(field: str) -> Callable[[np.ndarray, np.ndarray, int], np.ndarray]:
    """Inner-node aggregator for semantic payloads: the payload row of the child whose first
    slot has the highest ``field`` value (ties: the first child in OctoMap's child order)."""

    def aggregate(child_payload: np.ndarray, group: np.ndarray, n_groups: int) -> np.ndarray:
        score = np.asarray(child_payload[field])[:, 0].astype(np.float64)
        order = np.lexsort((-score, group))  # by group, then strongest first
        first = np.r_[True, group[order][1:] != group[order][:-1]]
        return child_payload[order[first]]

    return aggregate
