"""Node types: what one kind of octree keeps in a node, declared once, registered by its ``.ot``
id.

OctoMap makes a tree kind one C++ node class (``OcTreeNode``, ``ColorOcTreeNode``, ...): its
data, how an update changes it, how children aggregate into an inner node, when 8 children are
equal enough to prune, its ``writeData`` / ``readData``, and its ``sizeof``; the tree class is
registered under the id its ``.ot`` files carry (``AbstractOcTree::createTree``). A
:class:`NodeType` is evsmap's equivalent, as data:

* ``tree_id``: the ``.ot`` id (``ColorOcTree``, ``MultiClassBayesOcTree``, ...);
* ``columns``: the per-leaf payload arrays an updater keeps beside the log-odds (name, dtype,
  shape, fill of a new leaf);
* ``record``: the payload as the ``.ot`` stores it after the ``float32`` log-odds (a numpy
  dtype, written little-endian), with ``encode`` / ``decode`` between the columns and the
  records (default: field ``f`` is column ``f``; a plain record is the only column);
* ``update``: how a scan changes the payload, after OctoMap's occupancy update;
* ``inner``: how the children's payloads aggregate into an inner node; ``pruned``: the payload
  of a pruned node (``"first"``: child 0's, OctoMap's ``copyData``);
* ``prune_on``: the columns that must be exactly equal, besides the log-odds, for 8 leaf
  children to be pruned;
* ``node_bytes``: bytes of one node in the compared C++ system's memory (OctoMap's
  ``memoryUsage()`` model: ``MapStats.octomap_memory_bytes``);
* ``label`` / ``colour``: the column holding the most likely class (first slot) and the RGB
  colour, for queries, evaluation and PLY export;
* ``publish``: the file the compared system itself saves (``--file-format published``), when
  that is not the full state; ``message``: its full map as its ROS node sends it
  (``--file-format message``), when that differs from the saved file;
  is not the full state;
* ``uses_semantics``: whether ``update`` reads a segmenter's observation.

The rules (``update``, ``inner``, ``pruned`` callables, ``publish``) take the updater first, so
they can read its options (``theta``, ``psi``, ...), its map (``updater.map``) and helpers
(``updater.endpoint_voxels``). :data:`NODE_TYPES` maps ``.ot`` ids to node types; registering
a taken id raises, and :mod:`evsmap.mapping.octree_io` reads a file by its id through it.
OctoMap's own ``OcTree`` and ``ColorOcTree`` are registered here.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from evsmap.errors import DuplicateNameError, InvalidDataError, UnknownNameError
from evsmap.mapping.fusion.colour import average_frame_colours
from evsmap.mapping.tree import Tree, octomap_colour_average, octomap_colour_prune

if TYPE_CHECKING:
    from evsmap.data import Frame, SemanticObservation

__all__ = ["COLOR_FORMAT", "COLOR_OCTREE", "NODE_TYPES", "OCTREE", "Column", "NodeType",
           "NodeTypeRegistry"]

#: ``update(updater, frame, points, scan, observation)``: fuse a frame into the payload columns
#: after the occupancy update (``points``: :class:`evsmap.updaters.base.FramePoints`, ``scan``:
#: :class:`evsmap.mapping.occupancy.ScanUpdate`, ``observation``: the segmenter's, or None).
UpdateRule = Callable[..., None]

#: ``rule(updater, child_records, group, n_groups) -> records``: one payload record per parent
#: from its children's (``group``: the parent of every child row, sorted, children of a parent
#: in child order; see :data:`evsmap.mapping.tree.Aggregator`).
InnerRule = Callable[[Any, np.ndarray, np.ndarray, int], np.ndarray]

#: ``publish(updater, tree) -> (tree id, tree, record dtype or None)``: the file the compared
#: system writes.
PublishRule = Callable[[Any, Tree], tuple[str, Tree, np.dtype | None]]

_ID = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


@dataclass(frozen=True)
class Column:
    """One per-leaf payload array.

    Attributes:
        name: the array's name (``OccupancyMap.payload(name)``).
        dtype: its element type.
        shape: the shape of one leaf's row (``()`` for a scalar).
        fill: the value of a new leaf.
    """

    name: str
    dtype: Any
    shape: tuple[int, ...] = ()
    fill: Any = 0

    def __post_init__(self) -> None:
        object.__setattr__(self, "dtype", np.dtype(self.dtype))
        object.__setattr__(self, "shape", tuple(int(s) for s in self.shape))


@dataclass(frozen=True, eq=False)
class NodeType:
    """What one kind of tree keeps in a node (see the module notes).

    Args:
        tree_id: the ``.ot`` id, one identifier-like ASCII word.
        record: the ``.ot`` payload after the log-odds (numpy dtype), or None (occupancy only).
        columns: the per-leaf payload arrays.
        update: how a scan changes the columns (None: occupancy only).
        inner: payload of an inner node from its children's records (None: zero records).
        pruned: payload of a pruned node: ``"first"`` (child 0's) or an inner rule.
        prune_on: columns that must be equal, besides the log-odds, for pruning.
        node_bytes: in-memory bytes of one node (OctoMap's ``memoryUsage`` model).
        label: column whose first slot is the most likely class, or None.
        colour: column holding ``uint8`` r, g, b, or None.
        encode: ``encode(columns, n) -> records``; default by field name.
        decode: ``decode(records) -> {column: array}``; default by field name.
        publish: the file the compared system itself saves, or None (the full file is what it
            writes).
        message: its full map as its ROS node publishes it (``octomap_full``), when that is not
            the saved file, or None. Written to an ``.ot`` only under a tree id whose node
            layout it has (an OctoMap tool must refuse it, not misread it).
        colour_only: its ``ColorOcTree`` form (log-odds and one colour a node), or None: the
            VOC colour of the label column's first slot for a semantic type, the colour column
            otherwise (:meth:`~evsmap.updaters.base.OctreeUpdater.colour_only`).
        uses_semantics: ``update`` needs a segmenter's observation.
        description: one line for listings.
    """

    tree_id: str
    record: Any = None
    columns: tuple[Column, ...] = ()
    update: UpdateRule | None = None
    inner: InnerRule | None = None
    pruned: str | InnerRule = "first"
    prune_on: tuple[str, ...] = ()
    node_bytes: int = 16
    label: str | None = None
    colour: str | None = None
    encode: Callable[[Mapping[str, np.ndarray], int], np.ndarray] | None = None
    decode: Callable[[np.ndarray], Mapping[str, np.ndarray]] | None = None
    publish: PublishRule | None = None
    message: PublishRule | None = None
    colour_only: PublishRule | None = None
    uses_semantics: bool = False
    description: str = ""
    _names: tuple[str, ...] = field(default=(), init=False, repr=False)

    def __post_init__(self) -> None:
        if not isinstance(self.tree_id, str) or not _ID.fullmatch(self.tree_id):
            raise InvalidDataError(f"node type id must be one ASCII identifier (it is the .ot "
                                   f"file's 'id' word), got {self.tree_id!r}")
        if self.record is not None:
            object.__setattr__(self, "record", np.dtype(self.record))
        columns = tuple(self.columns)
        object.__setattr__(self, "columns", columns)
        names = tuple(c.name for c in columns)
        if len(set(names)) != len(names):
            raise InvalidDataError(f"node type {self.tree_id}: column names repeat: {names}")
        object.__setattr__(self, "_names", names)
        object.__setattr__(self, "prune_on", tuple(self.prune_on))
        for what, cols in (("prune_on", self.prune_on), ("label", (self.label,)),
                           ("colour", (self.colour,))):
            unknown = [c for c in cols if c is not None and c not in names]
            if unknown:
                raise InvalidDataError(f"node type {self.tree_id}: {what} names no column: "
                                       f"{unknown} (columns: {', '.join(names) or 'none'})")
        if not (isinstance(self.node_bytes, int) and self.node_bytes > 0):
            raise InvalidDataError(f"node type {self.tree_id}: node_bytes must be a positive "
                                   f"int, got {self.node_bytes!r}")
        if not (self.pruned == "first" or callable(self.pruned)):
            raise InvalidDataError(f"node type {self.tree_id}: pruned must be 'first' or a "
                                   f"rule, got {self.pruned!r}")

    @property
    def column_names(self) -> tuple[str, ...]:
        return self._names

    def __reduce__(self) -> tuple[Callable[[str], NodeType], tuple[str]]:
        """A registered node type pickles as its id (its rules may be lambdas or closures), so
        an updater holding one can cross a process boundary."""
        if NODE_TYPES._types.get(self.tree_id) is not self:
            raise TypeError(f"node type {self.tree_id!r} is not registered: only registered node "
                            f"types pickle (by their id)")
        return (_registered, (self.tree_id,))

    def to_record(self, columns: Mapping[str, np.ndarray], n: int) -> np.ndarray | None:
        """The payload records of ``n`` leaves from their columns (None without a record)."""
        if self.record is None:
            return None
        if self.encode is not None:
            return self.encode(columns, n)
        self._check_default_codec()
        if self.record.names is None:
            return np.asarray(columns[self._names[0]]).astype(self.record.base)
        rec = np.empty(n, dtype=self.record.newbyteorder("="))
        for name in self.record.names:
            rec[name] = columns[name]
        return rec

    def from_record(self, record: np.ndarray) -> dict[str, np.ndarray]:
        """The columns held in ``record`` (inverse of :meth:`to_record`)."""
        if self.decode is not None:
            return dict(self.decode(record))
        self._check_default_codec()
        if self.record.names is None:
            return {self._names[0]: record}
        return {name: record[name] for name in self.record.names}


    def _check_default_codec(self) -> None:
        """The default encode/decode needs record fields named like columns, or a plain record
        and one column."""
        fields = self.record.names or ()
        if fields and not set(fields) <= set(self._names):
            raise InvalidDataError(
                f"node type {self.tree_id}: record fields {list(fields)} are not all columns "
                f"({', '.join(self._names) or 'none'}); give it encode and decode")
        if not fields and len(self._names) != 1:
            raise InvalidDataError(f"node type {self.tree_id}: a plain record needs exactly one "
                                   f"column, or encode and decode")


class NodeTypeRegistry:
    """Node types by ``.ot`` id."""

    def __init__(self) -> None:
        self._types: dict[str, NodeType] = {}

    def add(self, node_type: NodeType) -> NodeType:
        """Register ``node_type`` under its id; returns it.

        Raises:
            DuplicateNameError: the id is taken by another node type.
        """
        if not isinstance(node_type, NodeType):
            raise InvalidDataError(f"expected a NodeType, got {type(node_type).__name__}")
        taken = self._types.get(node_type.tree_id)
        if taken is not None and taken is not node_type:
            raise DuplicateNameError(f"node type {node_type.tree_id!r} is already registered "
                                     f"({taken.description or 'another node type'})")
        self._types[node_type.tree_id] = node_type
        return node_type

    def remove(self, tree_id: str) -> None:
        """Unregister ``tree_id`` (tests; a plug-in replacing its own type)."""
        self.get(tree_id)
        del self._types[tree_id]

    def get(self, tree_id: str) -> NodeType:
        """The node type with id ``tree_id``.

        Raises:
            UnknownNameError: naming the known ids.
        """
        try:
            return self._types[tree_id]
        except KeyError:
            raise UnknownNameError(f"unknown tree id {tree_id!r} (known: "
                                   f"{', '.join(self.names())}; a plug-in's node type is known "
                                   f"once its module is imported)") from None

    def names(self) -> list[str]:
        return sorted(self._types)

    def __contains__(self, tree_id: object) -> bool:
        return tree_id in self._types

    def __iter__(self) -> Iterator[NodeType]:
        return iter(list(self._types.values()))


NODE_TYPES = NodeTypeRegistry()
"""Every node type evsmap can read, by ``.ot`` id."""


def _registered(tree_id: str) -> NodeType:
    """The registered node type ``tree_id`` (unpickling)."""
    return NODE_TYPES.get(tree_id)


# --------------------------------------------------------------------------- OctoMap's own

#: Payload layout of a ``ColorOcTreeNode`` after its float: ``uint8`` r, g, b.
COLOR_FORMAT = np.dtype((np.uint8, (3,)))


def _average_hit_colours(updater: Any, frame: Frame, points: Any, scan: Any,
                         observation: SemanticObservation | None) -> None:
    """``ColorOcTree::averageNodeColor`` of every hit voxel with its points' mean colour."""
    pixels, voxels, local = updater.endpoint_voxels(points)
    if voxels.size:
        average_frame_colours(updater.map.payload("rgb"), frame.colors(), pixels, voxels, local)


OCTREE = NODE_TYPES.add(NodeType(
    "OcTree", description="OctoMap OcTree: float log-odds (5 B a node in .ot)"))
"""OctoMap's occupancy-only tree."""

COLOR_OCTREE = NODE_TYPES.add(NodeType(
    "ColorOcTree", record=COLOR_FORMAT, columns=(Column("rgb", np.uint8, (3,), fill=255),),
    update=_average_hit_colours,
    inner=lambda updater, kids, group, n: octomap_colour_average(kids, group, n),
    pruned=lambda updater, kids, group, n: octomap_colour_prune(kids, group, n),
    colour="rgb", description="OctoMap ColorOcTree: log-odds + averaged r, g, b (8 B a node in "
                              ".ot); white = no colour"))
"""OctoMap's ``ColorOcTree``: a hit voxel's colour is ``averageNodeColor`` of its stored colour
and its points' mean (the first colour is copied; white, 255/255/255, is "no colour"); pruning
ignores colour; an inner node's colour is the average of its children's set colours
(``updateInnerOccupancy``), a pruned node's as ``ColorOcTree::pruneNode`` sets it."""
