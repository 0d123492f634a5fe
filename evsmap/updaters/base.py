"""Shared machinery of the octree map updaters: frame -> scan -> occupancy update, per-leaf
payloads, pruned-tree statistics and files.

An updater keeps its map as OctoMap's tree expanded to the finest level
(:class:`~evsmap.mapping.occupancy.OccupancyMap`: sorted leaf codes, log-odds and named payload
arrays). The pruned tree, which OctoMap keeps in memory and writes to its files, is built from the
leaves when it is needed (:meth:`OctreeUpdater.tree`): the two hold the same information because
OctoMap only prunes 8 identical children and expands them again before changing one.

What differs between kinds of map - the payload, its update, inner aggregation, prune equality,
bytes per node, label and colour, the ``.ot`` record - is the updater's
:class:`~evsmap.mapping.node_type.NodeType`; a new updater is a node type and a factory
(``docs/plugins.md``)."""

from __future__ import annotations

import contextlib
import functools
import math
from collections.abc import Iterator, Mapping
from dataclasses import replace
from os import PathLike
from pathlib import Path
from typing import ClassVar, Self

import numpy as np

from evsmap.data import Frame, Intrinsics, SemanticObservation
from evsmap.errors import DataFormatError, InvalidDataError
from evsmap.geometry import backproject, transform_points
from evsmap.interfaces import FILE_FORMATS, MapStats, MapUpdater, PointQuery
from evsmap.mapping.kernels import Kernels, check_kernels, depth_points, group_points
from evsmap.mapping.keys import KEY_MAX, KEY_OFFSET, pack, unpack
from evsmap.mapping.node_type import OCTREE, InnerRule, NodeType
from evsmap.mapping.occupancy import OccupancyMap, OccupancyParams
from evsmap.mapping.raycast import scan_keys
from evsmap.mapping.sensor_model import OCTOMAP
from evsmap.mapping.threads import kernel_threads
from evsmap.mapping.tree import Aggregator, Tree

OCTOMAP_BASE_BYTES = 320
"""``sizeof(OcTreeBaseImpl)`` that OctoMap's ``memoryUsage`` adds once per tree (x86-64)."""


class FramePoints:
    """A frame's valid depth pixels as world points, with the pixel attributes the updaters
    fuse (colour, semantics) in the same order, and the endpoint voxel of each point.

    Attributes:
        points: (N, 3) float64 world coordinates (computed on first use).
        origin: (3,) camera centre (sensor origin of a point-cloud frame).
        pixels: (N,) flat pixel index of each point (its index in a point-cloud frame), the
            index into :meth:`Frame.colors`.
        endpoint: (N,) bool, the point lies within the max range (its voxel is a hit).
        voxel_codes: sorted unique int64 codes of the voxels holding the points.
        point_voxel: (N,) index of each point's voxel in ``voxel_codes`` (-1: outside the map).
        rays: end points of the scan's rays (float32): the points, or with ``discretize`` the
            centres of their voxels (OctoMap's ``computeDiscreteUpdate``), computed here once.

    ``kernels`` (:data:`~evsmap.mapping.kernels.Kernels`): back-project and group the points
    with the compiled kernels (:func:`~evsmap.mapping.kernels.depth_points`,
    :func:`~evsmap.mapping.kernels.group_points`) or with numpy (:func:`octomap_keys` +
    :func:`group_keys`); the same voxels.
    """

    def __init__(self, frame: Frame, resolution: float, max_range: float,
                 discretize: bool = False, kernels: Kernels = "compiled") -> None:
        from evsmap.mapping.raycast import _norm, octomap_keys

        self._frame = frame
        self._points: np.ndarray | None = None
        compiled = kernels == "compiled"
        if frame.points is not None:  # a point-cloud frame
            self.pixels = np.arange(len(frame.points))
            self._points = transform_points(frame.points, frame.pose)
            pts = self._points.astype(np.float32)
        elif compiled and depth_points is not None:
            depth, i = _image(frame)
            self.pixels, pts = depth_points(depth, i.fx, i.fy, i.cx, i.cy, frame.pose)
        else:
            depth, i = _image(frame)
            valid = depth > 0
            self.pixels = np.flatnonzero(valid)
            self._points = backproject(depth, i, frame.pose, mask=valid)
            # the same float32 arithmetic as the ray casting (OctoMap's point3d)
            pts = self._points.astype(np.float32)
        self.origin = frame.pose[:3, 3].astype(np.float64)
        done = False
        if compiled and group_points is not None:
            self.point_voxel, ok, self.voxel_codes, done = group_points(
                pts, 1.0 / float(resolution), KEY_OFFSET, KEY_MAX, _DENSE_BOX)
        if not done:
            keys, ok = octomap_keys(pts, resolution)
            self.voxel_codes, inverse = group_keys(keys[ok])
            self.point_voxel = np.full(len(pts), -1, dtype=np.int64)
            self.point_voxel[ok] = inverse
        origin32 = self.origin.astype(np.float32)
        if discretize:  # the range test applies to the voxel centre the point is reduced to
            self.rays = ((unpack(self.voxel_codes) - KEY_OFFSET + 0.5) * resolution
                         ).astype(np.float32)
            inside = (_norm(self.rays - origin32) <= max_range if max_range >= 0
                      else np.ones(len(self.rays), dtype=bool))
            self.endpoint = ok.copy()
            self.endpoint[ok] = inside[self.point_voxel[ok]]
        else:
            self.rays = pts
            self.endpoint = ok & (_norm(pts - origin32) <= max_range) if max_range >= 0 else ok


    @property
    def points(self) -> np.ndarray:
        """(N, 3) float64 world coordinates of the points (computed on first use)."""
        if self._points is None:
            depth, intrinsics = _image(self._frame)
            self._points = backproject(depth, intrinsics, self._frame.pose, mask=depth > 0)
        return self._points


def _image(frame: Frame) -> tuple[np.ndarray, Intrinsics]:
    """The depth image and camera of an image frame (a frame without ``points``)."""
    assert frame.depth is not None and frame.intrinsics is not None  # an image frame
    return frame.depth, frame.intrinsics


_DENSE_BOX = 1 << 24
"""Largest key box (cells) :func:`group_keys` indexes densely instead of sorting."""


def group_keys(keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``np.unique`` of (N, 3) keys as packed codes, with the inverse: (sorted unique codes,
    position of each key among them). Inside a small box of keys (one frame's) it marks a dense
    grid instead of sorting, O(N + box)."""
    keys = np.asarray(keys, dtype=np.int64)
    if not len(keys):
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    lo = keys.min(axis=0)
    shape = keys.max(axis=0) - lo + 1
    size = int(np.prod(shape))
    if size > _DENSE_BOX:
        codes, inverse = np.unique(pack(keys), return_inverse=True)
        return codes, inverse.ravel()
    rel = keys - lo
    cell = (rel[:, 0] * shape[1] + rel[:, 1]) * shape[2] + rel[:, 2]  # same order as pack()
    mark = np.zeros(size, dtype=bool)
    mark[cell] = True
    cells = np.flatnonzero(mark)
    lut = np.empty(size, dtype=np.int64)
    lut[cells] = np.arange(len(cells))
    kz = cells % shape[2]
    kxy = cells // shape[2]
    unique = np.stack([kxy // shape[1], kxy % shape[1], kz], axis=1) + lo
    return pack(unique), lut[cell]


def check_observation(frame: Frame, observation: SemanticObservation | None,
                      updater: str) -> SemanticObservation:
    if observation is None:
        raise InvalidDataError(
            f"updater {updater!r} fuses semantics: give it a segmenter's observation "
            f"(e.g. --segmenter oracle)")
    frame.require_images(f"updater {updater!r}")
    depth, _ = _image(frame)
    if observation.shape != depth.shape:
        raise InvalidDataError(
            f"frame {frame.name!r}: observation is {observation.shape}, depth is "
            f"{depth.shape}")
    return observation


class OctreeUpdater(MapUpdater):
    """An octree map updater: OctoMap occupancy plus the payload of its node type.

    Everything a kind of tree keeps per node - its payload columns and ``.ot`` record, how a scan
    updates them, inner aggregation, prune equality, bytes per node, label and colour columns -
    is its :class:`~evsmap.mapping.node_type.NodeType`; this class does the rest (rays,
    occupancy, the pruned tree, files, queries) the same way for every node type. A subclass
    sets :attr:`node_type` (and adds its options); a plug-in can also pass ``node_type`` to a
    plain ``OctreeUpdater``.

    Args:
        node_type: the kind of tree (default: the class's :attr:`node_type`, OctoMap's
            ``OcTree``).
        name: the updater's name in messages (default: the class's :attr:`name`, else the
            node type's id).
        resolution: leaf edge length, metres.
        max_range: sensor max range, metres (negative: unlimited); points beyond it only clear
            free space up to it, as OctoMap's ``insertPointCloud``.
        discretize: reduce the end points to unique voxel centres before ray casting (OctoMap's
            ``discretize`` flag).
        prob_hit, prob_miss, clamp_min, clamp_max, occupancy_threshold: OctoMap's sensor model.
        kernels: ``"compiled"`` (numba kernels) or ``"reference"`` (the numpy code) for every
            loop of an update: points, rays and the node type's payload update
            (:data:`~evsmap.mapping.kernels.Kernels`); the same map either way.
    """

    name: str = ""
    node_type: NodeType = OCTREE
    has_leaf_map: ClassVar[bool] = True
    front_end: ClassVar[str | None] = "direct"

    def __init__(self, *, node_type: NodeType | None = None, name: str | None = None,
                 resolution: float = 0.05, max_range: float = 5.0,
                 discretize: bool = True, prob_hit: float = OCTOMAP.prob_hit,
                 prob_miss: float = OCTOMAP.prob_miss, clamp_min: float = OCTOMAP.clamp_min,
                 clamp_max: float = OCTOMAP.clamp_max,
                 occupancy_threshold: float = OCTOMAP.occupancy_threshold,
                 kernels: Kernels = "compiled") -> None:
        if node_type is not None:
            if not isinstance(node_type, NodeType):
                raise InvalidDataError(f"node_type must be a NodeType, got "
                                       f"{type(node_type).__name__}")
            self.node_type = node_type
        if name is not None:
            self.name = name
        elif not self.name:
            self.name = self.node_type.tree_id
        self.kernels = check_kernels(kernels)
        if not (isinstance(max_range, (int, float)) and math.isfinite(max_range)):
            raise InvalidDataError(f"max_range must be a finite number, got {max_range!r}")
        try:
            params = OccupancyParams(prob_hit=prob_hit, prob_miss=prob_miss,
                                     clamp_min=clamp_min, clamp_max=clamp_max,
                                     occupancy_threshold=occupancy_threshold)
            self.map = OccupancyMap(resolution, params)
        except ValueError as exc:
            raise InvalidDataError(str(exc)) from None
        self.resolution = float(resolution)
        self.params = params
        self.max_range = float(max_range)
        self.discretize = bool(discretize)
        self.frames = 0
        self._front_end_counts: dict[str, list[int]] = {"centroids": [], "hits": [], "rays": []}
        self._reusing = False
        self._reused_tree: Tree | None = None
        self._init_payloads()

    semantics_within_range: ClassVar[bool] = False
    """Whether :meth:`integrate` reads the observation only at end points within
    :attr:`max_range` (the direct front end, SSMI's generator); semantic_slam's node labels
    every centroid, beyond the range too."""

    def semantic_pixels(self, frame: Frame) -> np.ndarray | None:
        """The pixels whose semantics can reach the map: valid depth, and with
        :attr:`semantics_within_range` only those that may end inside the range. A point's range
        is at least its depth; the end point tested against the range may lie nearer than the
        point: its voxel centre (``discretize``, half a voxel diagonal) or the centroid of its
        voxel-grid cell (SSMI's generator front end, less than a cell diagonal; the cell's
        semantics average every point in it). So depth <= max range + two voxels keeps every
        pixel whose semantics can reach the map (a superset). None for every pixel: an updater
        without semantics or a point-cloud frame."""
        if not self.uses_semantics or frame.depth is None or frame.points is not None:
            return None
        depth = frame.depth
        if self.semantics_within_range and self.max_range >= 0:
            return (depth > 0) & (depth <= np.float32(self.max_range + 2 * self.resolution))
        return (depth > 0) & np.isfinite(depth)

    @property
    def tree_id(self) -> str:
        """The ``.ot`` id of the map's files (its node type's)."""
        return self.node_type.tree_id

    @property
    def uses_semantics(self) -> bool:
        return self.node_type.uses_semantics

    # -- the node type's parts, on this map ------------------------------------------------
    def _init_payloads(self) -> None:
        """Add the node type's payload columns to the (empty) leaf map."""
        for c in self.node_type.columns:
            self.map.add_payload(c.name, c.dtype, c.shape, fill=c.fill)

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

    def _equal_columns(self) -> list[np.ndarray]:
        """Arrays that must be identical for 8 children to be pruned."""
        return [self.map.logodds] + [self.map.payload(n) for n in self.node_type.prune_on]

    def _bound(self, rule: InnerRule | None) -> Aggregator | None:
        return None if rule is None else functools.partial(rule, self)

    # -- MapUpdater ------------------------------------------------------------------------
    def integrate(self, frame: Frame, observation: SemanticObservation | None = None) -> None:
        if self.uses_semantics:
            observation = check_observation(frame, observation, self.name)
        # the compiled kernels run on evsmap.mapping.threads' number of threads, set here in
        # the thread that launches them
        with kernel_threads():
            points = FramePoints(frame, self.resolution, self.max_range, self.discretize,
                                 self.kernels)
            # the rays are already discretized (once, in FramePoints) when that option is on
            keys = scan_keys(points.rays, points.origin, self.resolution,
                             max_range=self.max_range, discretize=False, kernels=self.kernels)
            update = self.map.apply(keys.free, keys.occupied)
            if self.node_type.update is not None:
                self.node_type.update(self, frame, points, update, observation)
        self.count_front_end(centroids=len(points.voxel_codes), hits=len(keys.occupied),
                             rays=len(points.rays))
        self.frames += 1

    def count_front_end(self, *, centroids: int, hits: int, rays: int) -> None:
        """Record one frame's front-end counts (:meth:`front_end_counts`)."""
        for name, value in (("centroids", centroids), ("hits", hits), ("rays", rays)):
            self._front_end_counts[name].append(int(value))

    def front_end_counts(self) -> dict[str, list[int]]:
        return {k: list(v) for k, v in self._front_end_counts.items()}

    def file_formats(self) -> tuple[str, ...]:
        has_colour = (self.node_type.colour_only is not None or self.tree_id == "ColorOcTree"
                      or self.node_type.label is not None or self.node_type.colour is not None)
        offered = ("full", "published") + (("colour",) if has_colour else ()) + (
            ("message",) if self.node_type.message is not None else ())
        return tuple(f for f in FILE_FORMATS if f in offered)

    def colour_only(self, tree: Tree) -> tuple[str, Tree, np.dtype | None]:
        """The map as a ``ColorOcTree``: the node type's rule, else the VOC colour of each node's
        most likely class (white without one) for a semantic type, else its colour column."""
        from evsmap.mapping.generator import pack_rgb, unpack_rgb, voc_colormap

        nt = self.node_type
        if nt.colour_only is not None:
            return nt.colour_only(self, tree)
        if self.tree_id == "ColorOcTree" or tree.payload is None:
            return "ColorOcTree", tree, None
        columns = nt.from_record(tree.payload)
        if nt.label is not None:
            labels = np.asarray(columns[nt.label]).reshape(tree.num_nodes, -1)[:, 0]
            table = pack_rgb(voc_colormap(max(int(labels.max(initial=0)) + 1, 1)))
            packed = np.where(labels >= 0, table[np.maximum(labels, 0)], 0xFFFFFF)
            colours = unpack_rgb(packed)
        else:
            assert nt.colour is not None  # file_formats() offers "colour" only then
            colours = np.asarray(columns[nt.colour], dtype=np.uint8)
        return "ColorOcTree", replace(tree, payload=colours), None

    def endpoint_voxels(self, points: FramePoints
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The frame's hits grouped by voxel: (flat pixel index of every point that ends inside
        the range, the map indices of the distinct hit voxels, and each point's position among
        them)."""
        sel = np.flatnonzero(points.endpoint)
        used, local = compact(points.point_voxel[sel], len(points.voxel_codes))
        voxels, found = self.map.index(points.voxel_codes[used])
        if not np.all(found):  # cannot happen: every end point voxel was just inserted
            raise RuntimeError("end point voxel missing from the map")
        return points.pixels[sel], voxels, local

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

        nt = self.node_type
        pruned: str | Aggregator = (nt.pruned if isinstance(nt.pruned, str)  # "first"
                                    else functools.partial(nt.pruned, self))
        return build_tree(self.map.codes, np.asarray(self.map.logodds),
                          payload=self._payload_record(), equal_columns=self._equal_columns(),
                          inner_payload=self._bound(nt.inner), prune_payload=pruned)

    def pruned_share(self) -> float | None:
        """The share of the finest leaves merged into pruned nodes (builds :meth:`tree`);
        None for an empty map."""
        from evsmap.mapping.keys import TREE_DEPTH

        leaves = self.map.num_leaves
        if not leaves:
            return None
        tree = self.tree()
        finest = int(np.count_nonzero(tree.is_leaf & (tree.depth == TREE_DEPTH)))
        return 1.0 - finest / int(leaves)

    def stats(self) -> MapStats:
        tree = self.tree()
        memory = tree.memory_bytes(node_bytes=self.node_type.node_bytes,
                                   base_bytes=OCTOMAP_BASE_BYTES)
        return MapStats(nodes=int(tree.num_nodes), leaves=int(tree.num_leaves),
                        octomap_memory_bytes=int(memory))

    def write(self, path: str | PathLike[str], file_format: str = "full") -> int:
        """Write the map (``.ot``: with payload; ``.bt``: occupancy only); returns the bytes.

        Args:
            file_format: ``"full"`` - the whole state, which :meth:`restore` reads back so
                mapping can continue; ``"published"`` - the file the compared system itself
                saves (the node type's ``publish``; the same as ``full`` where that is what it
                writes); ``"colour"`` - a ``ColorOcTree`` (:meth:`colour_only`); ``"message"``
                - the node type's ``message``, the map as the system's ROS node sends it, under
                the tree id of its node layout. ``.bt`` files are the same in all.
        """
        from evsmap.mapping.octree_io import write_bt, write_ot

        path = Path(path)
        tree = self.tree()
        if path.suffix == ".bt":  # occupancy only; OctoMap writes its own tree's id
            tree_id = self.tree_id if self.tree_id in ("OcTree", "ColorOcTree") else "OcTree"
            p = self.params
            return write_bt(path, tree, self.resolution, tree_id=tree_id,
                            occupancy_thres=p.occupancy_threshold, clamp_min=p.clamp_min,
                            clamp_max=p.clamp_max)
        tree_id, tree, fmt = self._file_tree(tree, file_format)
        return write_ot(path, tree, self.resolution, tree_id=tree_id, payload_format=fmt)

    def _file_tree(self, tree: Tree, file_format: str) -> tuple[str, Tree, np.dtype | None]:
        """(tree id, tree, record) of the ``.ot`` in ``file_format``."""
        if file_format not in FILE_FORMATS:
            raise InvalidDataError(f"file format must be one of {', '.join(FILE_FORMATS)}, "
                                   f"got {file_format!r}")
        if file_format == "colour":
            if file_format not in self.file_formats():
                raise InvalidDataError(f"{self.name}: its {self.tree_id} nodes have no colour "
                                       f"to write a colour file with")
            return self.colour_only(tree)
        if file_format == "message":
            if self.node_type.message is None:
                raise InvalidDataError(f"{self.name}: sends no map message other than its saved "
                                       f"file (--file-format published)")
            return self.node_type.message(self, tree)
        if file_format == "published" and self.node_type.publish is not None:
            return self.node_type.publish(self, tree)
        return self.tree_id, tree, self.node_type.record

    def size_readings(self) -> dict[str, int | None]:
        """The map's counts and its size under each reading from one build of the tree."""
        from evsmap.mapping.octree_io import ot_bytes

        tree = self.tree()
        sizes: dict[str, int | None] = {}
        for fmt in ("published", "colour", "message"):
            if fmt in self.file_formats():
                tree_id, t, rec = self._file_tree(tree, fmt)
                sizes[fmt] = len(ot_bytes(t, self.resolution, tree_id=tree_id,
                                          payload_format=rec))
            else:
                sizes[fmt] = None
        return {"nodes": int(tree.num_nodes), "leaves": int(tree.num_leaves),
                "published_bytes": sizes["published"],
                "message_bytes": (sizes["published"] if sizes["message"] is None
                                  else sizes["message"]),
                "colour_bytes": sizes["colour"],
                "memory_bytes": int(tree.memory_bytes(node_bytes=self.node_type.node_bytes,
                                                      base_bytes=OCTOMAP_BASE_BYTES))}

    def restore(self, path: str | PathLike[str]) -> Self:
        """Replace this map by the one saved in ``path`` (an ``.ot`` this updater wrote), so
        mapping continues from it; returns ``self``.

        Raises:
            DataFormatError: unreadable file, another tree id or another resolution.
        """
        _, tree = self._read_own(path)
        try:
            codes, values, payload = tree.expand()
        except InvalidDataError as exc:  # coarse leaves covering too many voxels
            raise DataFormatError(f"{path}: {exc}") from None
        order = np.argsort(codes, kind="stable")
        self.map = OccupancyMap.from_leaves(self.resolution, codes[order], values[order],
                                            params=self.params)
        self._init_payloads()
        self._set_payload_record(None if payload is None else payload[order])
        return self

    def _read_own(self, path: str | PathLike[str]) -> tuple[str, Tree]:
        """Read an ``.ot`` of this map's node type and resolution: ``(id, tree)``."""
        from evsmap.mapping.octree_io import read_ot

        fmt = self.node_type.record
        formats: Mapping[str, np.dtype] | None = None if fmt is None else {self.tree_id: fmt}
        tree_id, resolution, tree = read_ot(path, payload_format=formats)
        if tree_id != self.tree_id:
            raise DataFormatError(f"{path}: a {tree_id} file, not a {self.tree_id} map")
        # OctoMap writes "res" with 6 digits: a float resolution (0.05f) comes back as 0.05
        if np.float32(resolution) != np.float32(self.resolution):
            raise DataFormatError(f"{path}: resolution {resolution} m, this map uses "
                                  f"{self.resolution} m")
        return tree_id, tree

    def query(self, points: np.ndarray) -> PointQuery:
        """What the map knows at ``points``; occupied voxels carry the first slot of the node
        type's label column (-1 without one)."""
        label = self.node_type.label
        if label is None:
            return self.map.query(points)
        return self._labelled_query(points, label)

    def _labelled_query(self, points: np.ndarray, classes: str) -> PointQuery:
        """:meth:`query` with the label of occupied voxels read from payload ``classes``
        (its first slot: the most likely class)."""
        q = self.map.query(points)
        pos, found = self.map.index(point_codes(points, self.resolution))
        occupied = found & (q.state == 1)
        label = q.label.copy()
        stored = self.map.payload(classes)
        label[occupied] = stored.reshape(len(stored), -1)[pos[occupied], 0]
        return PointQuery(state=q.state, probability=q.probability, label=label)

    def memory_nbytes(self) -> int:
        """Bytes of the leaf arrays: codes, log-odds and every payload."""
        m = self.map
        arrays = [m.codes, m.logodds] + [m.payload(n) for n in m.payload_names]
        return int(sum(a.nbytes for a in arrays))

    def occupied_labels(self) -> tuple[np.ndarray, np.ndarray]:
        """The occupied leaves and their most likely class: (sorted ``int64`` codes, ``int16``
        labels), read through :meth:`query` at the leaf centres, so -1 where a leaf has no class
        (and everywhere for updaters without semantics)."""
        from evsmap.interfaces import OCCUPIED
        from evsmap.mapping.keys import key_to_coord

        occupied = self.map.classify_logodds(self.map.logodds) == OCCUPIED
        codes = np.array(self.map.codes[occupied])
        if not codes.size:
            return codes, np.zeros(0, dtype=np.int16)
        label = self.query(key_to_coord(unpack(codes), self.resolution)).label
        return codes, np.asarray(label, dtype=np.int16)


def point_codes(points: np.ndarray, resolution: float) -> np.ndarray:
    """Voxel codes of world points as OctoMap's ``search`` finds them; -1 outside the map."""
    from evsmap.mapping.raycast import octomap_keys

    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    finite = np.all(np.isfinite(pts), axis=1)
    keys, ok = octomap_keys(np.where(finite[:, None], pts, 0.0), resolution)
    codes = pack(keys)
    codes[~(ok & finite)] = -1
    return codes


def strongest_child(field: str):
    """Inner-node aggregator for semantic payloads: the payload row of the child whose first
    slot has the highest ``field`` value (ties: the first child in OctoMap's child order)."""

    def aggregate(child_payload: np.ndarray, group: np.ndarray, n_groups: int) -> np.ndarray:
        score = np.asarray(child_payload[field])[:, 0].astype(np.float64)
        order = np.lexsort((-score, group))  # by group, then strongest first
        first = np.r_[True, group[order][1:] != group[order][:-1]]
        return child_payload[order[first]]

    return aggregate


def compact(index: np.ndarray, size: int) -> tuple[np.ndarray, np.ndarray]:
    """``np.unique(index, return_inverse=True)`` for indices into an array of ``size`` rows,
    without sorting: (ascending unique indices, position of each input among them)."""
    present = np.zeros(size, dtype=bool)
    present[index] = True
    unique = np.flatnonzero(present)
    lut = np.cumsum(present, dtype=np.int64) - 1
    return unique, lut[index]
