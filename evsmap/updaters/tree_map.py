"""The tree-level base of evsmap's octree maps: options, the frame loop, files, restore and
queries, the same for every storage of the tree.

Two storages derive from :class:`OctreeMap`: the leaf arrays of evsmap's updaters
(:class:`evsmap.updaters.base.OctreeUpdater`: OctoMap's tree expanded to the finest level, the
pruned tree built when it is needed) and a compared system's own node pool
(:class:`baselines.semantic_slam.SemanticSlamMap`). A storage states how a frame changes it
(:meth:`OctreeMap.update_frame`), its pruned tree (:meth:`OctreeMap.tree`), its leaf view
(:meth:`OctreeMap.leaves`) and how a read tree becomes its state (:meth:`OctreeMap.load_tree`);
this class does the rest once: the options (:class:`~evsmap.mapping.options.OctreeOptions`),
front-end counts, statistics, every file format, :meth:`OctreeMap.restore`, queries.
"""

from __future__ import annotations

import abc
import math
from collections.abc import Mapping
from dataclasses import replace
from os import PathLike
from pathlib import Path
from typing import ClassVar, NamedTuple, Self

import numpy as np

from evsmap.data import Frame, SemanticObservation
from evsmap.errors import DataFormatError, InvalidDataError
from evsmap.interfaces import FILE_FORMATS, MapStats, MapUpdater, PointQuery
from evsmap.mapping.kernels import Kernels, check_kernels
from evsmap.mapping.keys import pack, unpack
from evsmap.mapping.node_type import OCTREE, FileTree, NodeType, RecordFormat
from evsmap.mapping.occupancy import OccupancyMap, OccupancyParams
from evsmap.mapping.options import OCTREE_DEFAULTS, OctreeOptions
from evsmap.mapping.threads import kernel_threads
from evsmap.mapping.tree import Tree

OCTOMAP_BASE_BYTES = 320
"""``sizeof(OcTreeBaseImpl)`` that OctoMap's ``memoryUsage`` adds once per tree (x86-64)."""

_D = OCTREE_DEFAULTS
_SENSOR = OCTREE_DEFAULTS.sensor


class FrontEndCounts(NamedTuple):
    """One frame's front-end counts: distinct end points (centroids), hits, rays cast."""

    centroids: int
    hits: int
    rays: int


def check_observation(frame: Frame, observation: SemanticObservation | None,
                      updater: str) -> SemanticObservation:
    """``observation`` for a semantic updater's ``frame``.

    Raises:
        InvalidDataError: no observation, a frame without images, or another image size.
    """
    if observation is None:
        raise InvalidDataError(
            f"updater {updater!r} fuses semantics: give it a segmenter's observation "
            f"(e.g. --segmenter oracle)")
    frame.require_images(f"updater {updater!r}")
    assert frame.depth is not None  # require_images
    if observation.shape != frame.depth.shape:
        raise InvalidDataError(
            f"frame {frame.name!r}: observation is {observation.shape}, depth is "
            f"{frame.depth.shape}")
    return observation


def octree_options(*, resolution: float, max_range: float, discretize: bool,
                   prob_hit: float, prob_miss: float, clamp_min: float, clamp_max: float,
                   occupancy_threshold: float, kernels: str) -> OctreeOptions:
    """The constructor's options checked and gathered.

    Raises:
        InvalidDataError: an unknown ``kernels``, a range that is not a finite number, a sensor
            model or a resolution OctoMap cannot use.
    """
    checked = check_kernels(kernels)
    if not (isinstance(max_range, (int, float)) and math.isfinite(max_range)):
        raise InvalidDataError(f"max_range must be a finite number, got {max_range!r}")
    try:
        sensor = OccupancyParams(prob_hit=prob_hit, prob_miss=prob_miss, clamp_min=clamp_min,
                                 clamp_max=clamp_max, occupancy_threshold=occupancy_threshold)
        OccupancyMap(resolution, sensor)  # checks the resolution
    except ValueError as exc:
        raise InvalidDataError(str(exc)) from None
    return OctreeOptions(resolution=float(resolution), max_range=float(max_range),
                         discretize=bool(discretize), sensor=sensor, kernels=checked)


class OctreeMap(MapUpdater):
    """An octree map: OctoMap occupancy plus the payload of its node type, in some storage.

    Args:
        node_type: the kind of node (default: the class's :attr:`node_type`, OctoMap's
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
            loop of an update (:data:`~evsmap.mapping.kernels.Kernels`); the same map either
            way.

    The defaults are :data:`~evsmap.mapping.options.OCTREE_DEFAULTS`; :attr:`options` holds the
    checked values (also as :attr:`resolution`, :attr:`max_range`, :attr:`discretize`,
    :attr:`params`, :attr:`kernels`).
    """

    name: str = ""
    node_type: NodeType = OCTREE
    front_end: ClassVar[str | None] = "direct"

    semantics_within_range: ClassVar[bool] = False
    """Whether :meth:`integrate` reads the observation only at end points within
    :attr:`max_range` (the direct front end, SSMI's generator); semantic_slam's node labels
    every centroid, beyond the range too."""

    def __init__(self, *, node_type: NodeType | None = None, name: str | None = None,
                 resolution: float = _D.resolution, max_range: float = _D.max_range,
                 discretize: bool = _D.discretize, prob_hit: float = _SENSOR.prob_hit,
                 prob_miss: float = _SENSOR.prob_miss, clamp_min: float = _SENSOR.clamp_min,
                 clamp_max: float = _SENSOR.clamp_max,
                 occupancy_threshold: float = _SENSOR.occupancy_threshold,
                 kernels: Kernels = _D.kernels) -> None:
        if node_type is not None:
            if not isinstance(node_type, NodeType):
                raise InvalidDataError(f"node_type must be a NodeType, got "
                                       f"{type(node_type).__name__}")
            self.node_type = node_type
        if name is not None:
            self.name = name
        elif not self.name:
            self.name = self.node_type.tree_id
        self.options = octree_options(
            resolution=resolution, max_range=max_range, discretize=discretize,
            prob_hit=prob_hit, prob_miss=prob_miss, clamp_min=clamp_min, clamp_max=clamp_max,
            occupancy_threshold=occupancy_threshold, kernels=kernels)
        self.kernels: Kernels = self.options.kernels
        self.resolution = self.options.resolution
        self.params = self.options.sensor
        self.max_range = self.options.max_range
        self.discretize = self.options.discretize
        self.frames = 0
        self._front_end_counts: dict[str, list[int]] = {"centroids": [], "hits": [], "rays": []}
        self.init_storage()

    # -- the storage ------------------------------------------------------------------------
    @abc.abstractmethod
    def init_storage(self) -> None:
        """Make the empty storage (called once the options are set)."""

    @abc.abstractmethod
    def update_frame(self, frame: Frame, observation: SemanticObservation | None
                     ) -> FrontEndCounts:
        """Change the map by one frame (its front end, occupancy and payload); returns the
        front end's counts. ``observation`` is checked when the node type uses semantics."""

    @abc.abstractmethod
    def tree(self) -> Tree:
        """The pruned octree of the current map."""

    @abc.abstractmethod
    def leaves(self) -> OccupancyMap:
        """The map's leaves expanded to the finest level, with the node type's columns."""

    @abc.abstractmethod
    def load_tree(self, tree: Tree, path: str | PathLike[str]) -> None:
        """Replace the state by ``tree``, read from ``path`` (checked: this node type and
        resolution)."""

    # -- MapUpdater -------------------------------------------------------------------------
    @property
    def tree_id(self) -> str:
        """The ``.ot`` id of the map's files (its node type's)."""
        return self.node_type.tree_id

    @property
    def uses_semantics(self) -> bool:
        return self.node_type.uses_semantics

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
        pixels: np.ndarray
        if self.semantics_within_range and self.max_range >= 0:
            pixels = (depth > 0) & (depth <= np.float32(self.max_range + 2 * self.resolution))
        else:
            pixels = (depth > 0) & np.isfinite(depth)
        return pixels

    def integrate(self, frame: Frame, observation: SemanticObservation | None = None) -> None:
        if self.uses_semantics:
            observation = check_observation(frame, observation, self.name)
        # the compiled kernels run on evsmap.mapping.threads' number of threads, set here in
        # the thread that launches them (numba's setting is per thread)
        with kernel_threads():
            counts = self.update_frame(frame, observation)
        self.count_front_end(centroids=counts.centroids, hits=counts.hits, rays=counts.rays)
        self.frames += 1

    def count_front_end(self, *, centroids: int, hits: int, rays: int) -> None:
        """Record one frame's front-end counts (:meth:`front_end_counts`)."""
        for name, value in (("centroids", centroids), ("hits", hits), ("rays", rays)):
            self._front_end_counts[name].append(int(value))

    def front_end_counts(self) -> dict[str, list[int]]:
        return {k: list(v) for k, v in self._front_end_counts.items()}

    def stats(self) -> MapStats:
        tree = self.tree()
        memory = tree.memory_bytes(node_bytes=self.node_type.node_bytes,
                                   base_bytes=OCTOMAP_BASE_BYTES)
        return MapStats(nodes=int(tree.num_nodes), leaves=int(tree.num_leaves),
                        octomap_memory_bytes=int(memory))

    def pruned_share(self) -> float | None:
        """The share of the finest leaves merged into pruned nodes (builds :meth:`tree`);
        None for an empty map."""
        from evsmap.mapping.keys import TREE_DEPTH

        leaves = self.leaves().num_leaves
        if not leaves:
            return None
        tree = self.tree()
        finest = int(np.count_nonzero(tree.is_leaf & (tree.depth == TREE_DEPTH)))
        return 1.0 - finest / int(leaves)

    # -- files ------------------------------------------------------------------------------
    def file_formats(self) -> tuple[str, ...]:
        nt = self.node_type
        has_colour = (self.tree_id == "ColorOcTree" or nt.label is not None
                      or nt.colour is not None)
        offered = ("full", "published") + (("colour",) if has_colour else ()) + (
            ("message",) if nt.message_tree_id is not None else ())
        return tuple(f for f in FILE_FORMATS if f in offered)

    def full_file(self, tree: Tree) -> FileTree:
        """The whole state, which :meth:`restore` reads back."""
        return FileTree(self.tree_id, tree, self.node_type.record)

    def published_file(self, tree: Tree) -> FileTree:
        """The file the compared system itself saves (the full file by default)."""
        return self.full_file(tree)

    def message_file(self, tree: Tree) -> FileTree:
        """The full map as the system's ROS node sends it, under the node type's
        ``message_tree_id`` (only where it sets one)."""
        raise InvalidDataError(f"{self.name}: sends no map message other than its saved "
                               f"file (--file-format published)")

    def colour_file(self, tree: Tree) -> FileTree:
        """The map as a ``ColorOcTree``: the VOC colour of each node's most likely class (white
        without one) for a semantic type, else its colour column."""
        from evsmap.mapping.generator import pack_rgb, unpack_rgb, voc_colormap

        nt = self.node_type
        if self.tree_id == "ColorOcTree" or tree.payload is None:
            return FileTree("ColorOcTree", tree, None)
        columns = nt.from_record(tree.payload)
        if nt.label is not None:
            labels = np.asarray(columns[nt.label]).reshape(tree.num_nodes, -1)[:, 0]
            table = pack_rgb(voc_colormap(max(int(labels.max(initial=0)) + 1, 1)))
            packed = np.where(labels >= 0, table[np.maximum(labels, 0)], 0xFFFFFF)
            colours = unpack_rgb(packed)
        else:
            assert nt.colour is not None  # file_formats() offers "colour" only then
            colours = np.asarray(columns[nt.colour], dtype=np.uint8)
        return FileTree("ColorOcTree", replace(tree, payload=colours), None)

    def write(self, path: str | PathLike[str], file_format: str = "full") -> int:
        """Write the map (``.ot``: with payload; ``.bt``: occupancy only); returns the bytes.

        Args:
            file_format: ``"full"`` - the whole state, which :meth:`restore` reads back so
                mapping can continue; ``"published"`` - the file the compared system itself
                saves (:meth:`published_file`; the same as ``full`` where that is what it
                writes); ``"colour"`` - a ``ColorOcTree`` (:meth:`colour_file`); ``"message"``
                - :meth:`message_file`, the map as the system's ROS node sends it, under the
                tree id of its node layout. ``.bt`` files are the same in all.
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

    def _file_tree(self, tree: Tree, file_format: str) -> FileTree:
        """The ``.ot`` in ``file_format``."""
        if file_format not in FILE_FORMATS:
            raise InvalidDataError(f"file format must be one of {', '.join(FILE_FORMATS)}, "
                                   f"got {file_format!r}")
        if file_format == "colour":
            if file_format not in self.file_formats():
                raise InvalidDataError(f"{self.name}: its {self.tree_id} nodes have no colour "
                                       f"to write a colour file with")
            return self.colour_file(tree)
        if file_format == "message":
            return self.message_file(tree)
        if file_format == "published":
            return self.published_file(tree)
        return self.full_file(tree)

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
        self.load_tree(self._read_own(path), path)
        return self

    def _read_own(self, path: str | PathLike[str]) -> Tree:
        """The tree of an ``.ot`` of this map's node type and resolution."""
        from evsmap.mapping.octree_io import read_ot

        fmt = self.node_type.record
        formats: Mapping[str, RecordFormat] | None = (None if fmt is None
                                                      else {self.tree_id: fmt})
        tree_id, resolution, tree = read_ot(path, payload_format=formats)
        if tree_id != self.tree_id:
            raise DataFormatError(f"{path}: a {tree_id} file, not a {self.tree_id} map")
        # OctoMap writes "res" with 6 digits: a float resolution (0.05f) comes back as 0.05
        if np.float32(resolution) != np.float32(self.resolution):
            raise DataFormatError(f"{path}: resolution {resolution} m, this map uses "
                                  f"{self.resolution} m")
        return tree

    # -- queries ----------------------------------------------------------------------------
    def query(self, points: np.ndarray) -> PointQuery:
        """What the map knows at ``points``; occupied voxels carry the first slot of the node
        type's label column (-1 without one)."""
        label = self.node_type.label
        if label is None:
            return self.leaves().query(points)
        return self._labelled_query(points, label)

    def _labelled_query(self, points: np.ndarray, classes: str) -> PointQuery:
        """:meth:`query` with the label of occupied voxels read from payload ``classes``
        (its first slot: the most likely class)."""
        leaves = self.leaves()
        q = leaves.query(points)
        pos, found = leaves.index(point_codes(points, self.resolution))
        occupied = found & (q.state == 1)
        label = q.label.copy()
        stored = leaves.payload(classes)
        label[occupied] = stored.reshape(len(stored), -1)[pos[occupied], 0]
        return PointQuery(state=q.state, probability=q.probability, label=label)

    def occupied_labels(self) -> tuple[np.ndarray, np.ndarray]:
        """The occupied leaves and their most likely class: (sorted ``int64`` codes, ``int16``
        labels), read through :meth:`query` at the leaf centres, so -1 where a leaf has no class
        (and everywhere for updaters without semantics)."""
        from evsmap.interfaces import OCCUPIED
        from evsmap.mapping.keys import key_to_coord

        leaves = self.leaves()
        occupied = leaves.classify_logodds(leaves.logodds) == OCCUPIED
        codes = np.array(leaves.codes[occupied])
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
