"""``classic-semantic`` as semantic_slam runs it: the "traditional voxel node update strategy" of
EVSMaP's reference [14] (floatlazer/semantic_slam, ``octomap_generator``), the TESAMap / TFEAGMap
rows of Table IV.

One frame, as ``OctomapGenerator::insertPointCloud`` and ``semantic_cloud.py`` do it:

1. **The semantic cloud** (``semantic_cloud.py``): every pixel with a valid depth becomes a point
   in the camera frame (``float32``) with its colour, its top-3 classes as colours of the PASCAL
   VOC colour map packed ``0x00RRGGBB`` into float fields, and their confidences (the max variant:
   the top class and its confidence). Invalid depth is NaN in the ROS ``32FC1`` depth image the
   node reads, so those pixels are dropped by the next step.
2. **PCL's VoxelGrid** at the map resolution, in the camera frame: one centroid per leaf with
   every float field averaged - the packed class colours too, so a leaf mixing classes gets a
   colour that is none of them - and the colour through its r/g/b bytes.
3. The centroids are moved to the world frame (``float``). A centroid beyond ``max_range``
   (5 m) is not inserted; one beyond ``raycast_range`` (2 m) gets ``updateNode(hit)`` on its
   voxel at once and its ray is cut at ``raycast_range + 2 * resolution`` (free space up to
   ``raycast_range`` only); the rest are inserted with ``insertPointCloud(maxrange=raycast_range,
   discretize=true)``. Every ``updateNode`` runs with ``lazy_eval`` false: OctoMap expands pruned
   nodes on the way down and prunes on the way up, comparing log-odds and semantics.
4. Every centroid, in the voxel grid's order and without a range check, then averages its colour
   into and fuses its semantics with the node OctoMap's ``search`` returns - a pruned node takes
   it for its whole block, a missing voxel is skipped, two centroids in one voxel fuse twice.
5. ``updateInnerOccupancy``: inner nodes get the max log-odds, the average child colour and their
   children's semantics fused pairwise in child order.

The tree is kept as OctoMap keeps it (a node pool, :mod:`baselines.semantic_slam_kernels`), so
its node count, pruning and file are semantic_slam's. ``published`` files are semantic_slam's
``ColorOcTree`` (log-odds and the top semantic colour a node); ``full`` files keep the whole node
state and reload. The defaults are semantic_slam's ``octomap_generator.yaml``: ``max_range`` 5,
``raycast_range`` 2, clamping 0.12 / 0.97, hit 0.7, miss 0.4.

The node types (:mod:`baselines.semantic_slam_node`, ``.ot`` ids ``SemanticSlamOcTreeBayes`` /
``SemanticSlamOcTreeMax``) declare the file record, the memory model and the label and colour
columns of the leaf view. The storage is the node pool's: this updater derives from the
tree-level base :class:`~evsmap.updaters.tree_map.OctreeMap` (files, restore, queries), beside
evsmap's leaf arrays, and states the frame update, the tree, its leaf view and how a read tree
fills the pool; the front end is the shared
:class:`~evsmap.mapping.front_end.GeneratorFrontEnd` with semantic_slam's own cloud fields and
voxel grid.
"""

from __future__ import annotations

from dataclasses import asdict, replace
from os import PathLike
from typing import Any

import numpy as np

from baselines import semantic_slam_kernels as k
from baselines.semantic_slam_node import (
    FUSION_RULES,
    NODE_TYPES_BY_RULE,
    pack_rgb,
    unpack_rgb,
    voc_colormap,
)
from evsmap.data import Frame, SemanticObservation
from evsmap.errors import InvalidDataError
from evsmap.mapping.front_end import GeneratorFrontEnd
from evsmap.mapping.generator import as_float_parameter
from evsmap.mapping.keys import pack, unpack
from evsmap.mapping.node_type import FileTree
from evsmap.mapping.occupancy import OccupancyMap
from evsmap.mapping.options import OCTREE_DEFAULTS
from evsmap.mapping.raycast import octomap_keys, scan_keys
from evsmap.mapping.tree import Tree
from evsmap.updaters.tree_map import FrontEndCounts, OctreeMap

WHITE = k.WHITE

ROS_DEFAULTS: dict[str, float] = {
    "resolution": OCTREE_DEFAULTS.resolution, "max_range": 5.0,
    **asdict(replace(OCTREE_DEFAULTS.sensor, clamp_min=0.12, clamp_max=0.97))}
"""semantic_slam's ``params/octomap_generator.yaml`` but for the resolution (its 0.02 m; evsmap's
updaters default to :data:`~evsmap.mapping.options.OCTREE_DEFAULTS`' and Table IV sets its own),
each rounded to ``float`` as the node reads them."""

Pool = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]
"""The node pool's arrays as the kernels take them: state, children, value, rgb, colours,
confidences."""


class SemanticSlamMap(OctreeMap):
    """semantic_slam's semantic octree, Bayesian (top 3) or max fusion, on the
    ``octomap_generator`` front end (:mod:`evsmap.mapping.generator`).

    Args:
        fusion_rule: ``"bayes"`` (``SemanticsOcTree<SemanticsBayesian>``) or ``"max"``.
        raycast_range: free space is cast up to here; farther points are hits without rays.
        max_range: centroids beyond it are not inserted (their semantics still fuse into
            existing nodes, as in semantic_slam).
        (other arguments: :class:`~evsmap.updaters.tree_map.OctreeMap`; ``discretize`` is
        always on, as semantic_slam calls ``insertPointCloud``)
    """

    front_end = "generator"
    has_leaf_map = True

    def __init__(self, *, fusion_rule: str = "bayes", raycast_range: float = 2.0,
                 **kwargs: Any) -> None:
        if fusion_rule not in FUSION_RULES:
            raise InvalidDataError(f"unknown fusion rule {fusion_rule!r} (known: bayes, max)")
        if not (isinstance(raycast_range, (int, float)) and np.isfinite(raycast_range)
                and raycast_range >= 0):
            raise InvalidDataError(f"classic-semantic: raycast_range must be a number of metres "
                                   f">= 0, got {raycast_range!r}")
        self.fusion_rule = fusion_rule
        self.bayes = fusion_rule == "bayes"
        self.slots = 3 if self.bayes else 1
        self.raycast_range = as_float_parameter(raycast_range)
        self.default_conf = np.float32(1.0 if self.bayes else 0.0)
        self._leaves: OccupancyMap | None = None
        self._tree: Tree | None = None
        self.num_classes = 256
        self.fusions = 0
        self.centroids = 0
        # the ROS node keeps every parameter in a float member (evsmap.mapping.generator)
        for name, default in ROS_DEFAULTS.items():
            value = kwargs.get(name, default)
            if isinstance(value, (int, float)) and not isinstance(value, bool):
                kwargs[name] = as_float_parameter(value)
        super().__init__(node_type=NODE_TYPES_BY_RULE[fusion_rule],
                         name="classic-semantic" if self.bayes else "classic-semantic-max",
                         **kwargs)
        p = self.params
        self._lo = np.float32(p.clamp_min_logodds)
        self._hi = np.float32(p.clamp_max_logodds)
        self._hit = np.float32(p.hit_logodds)
        self._miss = np.float32(p.miss_logodds)

    # ---- the node pool
    def init_storage(self) -> None:
        self._allocate(1 << 12)

    def _allocate(self, capacity: int) -> None:
        self._state = np.array([-1, 0, 0], dtype=np.int64)
        self._children = np.full((capacity, 8), -1, dtype=np.int32)
        self._value = np.zeros(capacity, dtype=np.float32)
        self._rgb = np.full((capacity, 3), 255, dtype=np.uint8)
        self._colors = np.full((capacity, self.slots), WHITE, dtype=np.uint32)
        self._conf = np.full((capacity, self.slots), self.default_conf, dtype=np.float32)
        self._free = np.zeros(capacity, dtype=np.int64)

    def _grow(self) -> None:
        cap = len(self._value) * 2

        def grow(a: np.ndarray, fill: float) -> np.ndarray:
            out = np.empty((cap, *a.shape[1:]), dtype=a.dtype)
            out[:len(a)] = a
            out[len(a):] = fill
            return out

        self._children = grow(self._children, -1)
        self._value = grow(self._value, 0)
        self._rgb = grow(self._rgb, 255)
        self._colors = grow(self._colors, WHITE)
        self._conf = grow(self._conf, float(self.default_conf))
        self._free = grow(self._free, 0)

    def _pool(self) -> Pool:
        return (self._state, self._children, self._value, self._rgb, self._colors, self._conf)

    def _update(self, keys: np.ndarray, hits: np.ndarray) -> None:
        keys = np.ascontiguousarray(keys, dtype=np.int64).reshape(-1, 3)
        hits = np.ascontiguousarray(hits, dtype=np.bool_)
        start = 0
        while start < len(keys):
            start = k.update_nodes(keys, hits, start, *self._pool(), self._free, self._hit,
                                   self._miss, self._lo, self._hi, self.default_conf)
            if start < len(keys):
                self._grow()

    @property
    def num_nodes(self) -> int:
        return int(self._state[k.USED] - self._state[k.FREE_TOP])

    def memory_nbytes(self) -> int:
        """Bytes of the arrays holding the tree's nodes (the pool's used rows)."""
        used = int(self._state[k.USED])
        per_row = sum(a[:1].nbytes for a in (self._children, self._value, self._rgb,
                                              self._colors, self._conf))
        return used * per_row

    # ---- the leaf view (queries, PLY, scores) is built from the tree when asked for
    @property
    def map(self) -> OccupancyMap:
        """The leaf view, built from the tree when first asked for after a change."""
        if self._leaves is None:
            self._leaves = self._materialize()
        return self._leaves

    def leaves(self) -> OccupancyMap:
        return self.map

    def _materialize(self) -> OccupancyMap:
        tree = self.tree()
        out = OccupancyMap(self.resolution, self.params)
        payload = np.zeros(0, dtype=self.node_type.record)
        if tree.num_nodes:
            codes, values, expanded = tree.expand()
            assert expanded is not None  # the pool's tree has its payload
            out = OccupancyMap.from_leaves(self.resolution, codes, values, self.params)
            payload = expanded[np.argsort(codes, kind="stable")]
        out.add_payload("rgb", np.uint8, (3,), fill=255)[:] = payload["rgb"]
        out.add_payload("sem_colors", np.uint32, (self.slots,), fill=WHITE)[:] = \
            payload["colors"].reshape(-1, self.slots)
        out.add_payload("sem_classes", np.int16, (self.slots,), fill=-1)[:] = \
            self.colour_classes(payload["colors"].reshape(-1, self.slots))
        return out

    def colour_classes(self, colours: np.ndarray) -> np.ndarray:
        """Class ids of packed semantic colours under the VOC colour map; -1 for white and for
        colours that are no class's (an averaged colour)."""
        table = pack_rgb(voc_colormap(self.num_classes))
        order = np.argsort(table, kind="stable")
        sorted_table = table[order]
        c = np.asarray(colours, dtype=np.uint32)
        pos = np.clip(np.searchsorted(sorted_table, c), 0, len(table) - 1)
        hit = sorted_table[pos] == c
        return np.where(hit, order[pos], -1).astype(np.int16)

    def _stale(self) -> None:
        self._leaves = None
        self._tree = None

    # ---- one frame
    def update_frame(self, frame: Frame, observation: SemanticObservation | None
                     ) -> FrontEndCounts:
        assert observation is not None  # uses_semantics: integrate checked it
        self.num_classes = max(self.num_classes if self.frames else 0,
                               int(observation.num_classes))
        colors = frame.colors()
        cloud = GeneratorFrontEnd(self.name, self.resolution, grid=k.voxel_grid).cloud(
            frame, lambda pixels: self._cloud_fields(observation, colors, pixels))
        self.centroids += len(cloud.centroids)
        world, origin = cloud.centroids, cloud.origin
        dist = cloud.distance()
        inside = dist.astype(np.float64) <= self.max_range
        near = inside & (dist.astype(np.float64) <= self.raycast_range)
        far = inside & ~near
        ends = world.copy()
        if far.any():
            ends[far] = self._cut_rays(world[far] - origin, origin)
            fk, fok = octomap_keys(world[far], self.resolution)
            self._update(fk[fok], np.ones(int(fok.sum()), dtype=bool))
        rays = ends[inside]
        if len(rays):
            keys = scan_keys(rays, origin.astype(np.float64), self.resolution,
                             max_range=self.raycast_range, discretize=True,
                             kernels=self.kernels)
            self._update(unpack(keys.free), np.zeros(len(keys.free), dtype=bool))
            self._update(unpack(keys.occupied), np.ones(len(keys.occupied), dtype=bool))
        # colours and semantics of every centroid, in the voxel grid's order
        ck, cok = octomap_keys(world, self.resolution)
        sem = np.ascontiguousarray(cloud.fields[:, :self.slots]).view(np.uint32)
        conf = np.ascontiguousarray(cloud.fields[:, self.slots:])
        self.fusions += int(k.fuse_points(ck, cok, cloud.rgb, sem, conf, colors is not None,
                                          *self._pool(), self.bayes))
        self._stale()
        return FrontEndCounts(centroids=len(world), hits=int(np.count_nonzero(inside)),
                              rays=len(rays))

    def _cloud_fields(self, observation: SemanticObservation, colors: np.ndarray | None,
                      pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``semantic_cloud.py``'s float fields: packed class colours (as float bits) and
        confidences, and the colours."""
        palette = pack_rgb(voc_colormap(self.num_classes))
        fields, rgb = k.cloud_fields(
            pixels, np.ascontiguousarray(observation.classes.reshape(-1, observation.k)),
            np.ascontiguousarray(observation.probs.reshape(-1, observation.k), np.float32),
            self.slots, palette,
            np.zeros((0, 3), np.uint8) if colors is None
            else np.ascontiguousarray(colors.reshape(-1, 3), np.uint8))
        return fields, rgb

    def _cut_rays(self, d: np.ndarray, origin: np.ndarray) -> np.ndarray:
        """The end of each far centroid's ray: ``point3d::normalized`` (float norm, double
        sqrt, divide by the float length), then origin + direction * float(raycast_range + 2
        res)."""
        length = np.sqrt(((d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1])
                          + d[:, 2] * d[:, 2]).astype(np.float64)).astype(np.float32)
        direction = d / length[:, None]
        scale = np.float32(self.raycast_range + self.resolution * 2)
        ends: np.ndarray = origin + direction * scale
        return ends

    # ---- the tree, files
    def tree(self) -> Tree:
        if self._tree is None:
            depth, keys, mask, value, rgb, colors, conf = k.export(
                *self._pool(), self.bayes, self.default_conf)
            payload = np.empty(len(depth), dtype=self.node_type.record)
            payload["rgb"] = rgb
            payload["colors"] = colors.reshape(len(depth), self.slots)
            payload["conf"] = conf.reshape(len(depth), self.slots)
            self._tree = Tree(depth.astype(np.uint8), pack(keys), mask.astype(np.uint8),
                              value.astype(np.float32), payload)
        return self._tree

    def published_file(self, tree: Tree) -> FileTree:
        """semantic_slam's file: ``writeData`` writes the log-odds and ``getSemanticColor`` (the
        first semantic colour; white when unset) of every node under the type ``ColorOcTree``."""
        assert tree.payload is not None  # a tree of this node type has its payload
        top = np.asarray(tree.payload["colors"]).reshape(tree.num_nodes, self.slots)[:, 0]
        return FileTree("ColorOcTree", replace(tree, payload=unpack_rgb(top)), None)

    def colour_file(self, tree: Tree) -> FileTree:
        """The published file (it is a ``ColorOcTree``)."""
        return self.published_file(tree)

    def load_tree(self, tree: Tree, path: str | PathLike[str]) -> None:
        """The read tree into the node pool."""
        n = tree.num_nodes
        self._allocate(max(n + k.HEADROOM, 1 << 12))
        if n:
            assert tree.payload is not None  # read with this node type's record
            parents = tree.parents()
            index = tree.child_index()
            rows = np.arange(1, n)
            self._children[parents[rows], index[rows]] = rows
            self._value[:n] = tree.value
            self._rgb[:n] = tree.payload["rgb"]
            self._colors[:n] = tree.payload["colors"].reshape(n, self.slots)
            self._conf[:n] = tree.payload["conf"].reshape(n, self.slots)
            self._state[:] = (0, n, 0)
        self._stale()
