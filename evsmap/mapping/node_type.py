"""Node types: what one kind of octree keeps in a node, declared once, registered by its ``.ot``
id.

OctoMap splits a tree kind in two: the node class (``OcTreeNode``, ``ColorOcTreeNode``, ...) holds
the data, reads and writes it (``readData`` / ``writeData``) and says when children are equal
enough to prune; the tree class (``OcTree``, ``ColorOcTree``, ...) holds the rules - how an update
changes a node (``updateNode``, ``averageNodeColor``), inner nodes (``updateInnerOccupancy``),
pruning (``pruneNode``) - and is registered under the id its ``.ot`` files carry
(``AbstractOcTree::createTree``). evsmap does the same: a :class:`NodeType` is the node, as data:

* ``tree_id``: the ``.ot`` id (``ColorOcTree``, ``MultiClassBayesOcTree``, ...);
* ``columns``: the per-leaf payload arrays an updater keeps beside the log-odds (name, dtype,
  shape, fill of a new leaf);
* ``record``: the payload as the ``.ot`` stores it after the ``float32`` log-odds (a numpy
  dtype, written little-endian), with ``encode`` / ``decode`` between the columns and the
  records (default: field ``f`` is column ``f``; a plain record is the only column);
* ``prune_on``: its pruning predicate, the columns that must be exactly equal, besides the
  log-odds, for 8 leaf children to be pruned;
* ``node_bytes``: bytes of one node in the compared C++ system's memory (OctoMap's
  ``memoryUsage()`` model: ``MapStats.octomap_memory_bytes``);
* ``label`` / ``colour``: the column holding the most likely class (first slot) and the RGB
  colour, for queries, evaluation, PLY export and the colour-only file;
* ``message_tree_id``: the ``.ot`` id of the nodes of its ROS node's full map message
  (``--file-format message``), when that differs from the saved file;
* ``uses_semantics``: whether its tree's update reads a segmenter's observation.

The rules are typed methods of the tree, :class:`evsmap.updaters.base.OctreeUpdater` and its
subclasses (``update_payload``, ``inner_payload``, ``pruned_payload``, ``prune_columns``,
``published_file``, ``message_file``, ``colour_file``), so mypy checks them against the options
they read. :data:`NODE_TYPES` maps ``.ot`` ids to node types; registering a taken id raises, and
:mod:`evsmap.mapping.octree_io` reads a file by its id through it. OctoMap's own ``OcTree`` and
``ColorOcTree`` are registered here; evsmap's other built-in types are known by id from
:data:`BUILTIN_NODE_MODULES`, their modules imported when an id is first asked for.
"""

from __future__ import annotations

import importlib
import re
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from typing import NamedTuple, TypeAlias

import numpy as np
import numpy.typing as npt

from evsmap.errors import DuplicateNameError, InvalidDataError, UnknownNameError
from evsmap.mapping.tree import Tree

__all__ = ["BUILTIN_NODE_MODULES", "COLOR_FORMAT", "COLOR_OCTREE", "NODE_TYPES", "OCTREE",
           "Column", "FileTree", "NodeType", "NodeTypeRegistry", "RecordFormat"]

RecordFormat: TypeAlias = "np.dtype[np.generic]"
"""A node payload's ``.ot`` record layout (a numpy dtype)."""


class FileTree(NamedTuple):
    """What one ``.ot`` file holds: its tree id, the tree, the payload record layout (None for a
    layout the reader knows by the id)."""

    tree_id: str
    tree: Tree
    record: RecordFormat | None


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
    dtype: npt.DTypeLike
    shape: tuple[int, ...] = ()
    fill: float | np.generic = 0

    def __post_init__(self) -> None:
        object.__setattr__(self, "dtype", np.dtype(self.dtype))
        object.__setattr__(self, "shape", tuple(int(s) for s in self.shape))


Encoder = Callable[[Mapping[str, np.ndarray], int], np.ndarray]
"""``encode(columns, n) -> records``: the ``.ot`` records of ``n`` leaves from their columns."""

Decoder = Callable[[np.ndarray], Mapping[str, np.ndarray]]
"""``decode(records) -> {column: array}``: the inverse of an :data:`Encoder`."""


@dataclass(frozen=True, eq=False)
class NodeType:
    """What one kind of tree keeps in a node (see the module notes).

    Args:
        tree_id: the ``.ot`` id, one identifier-like ASCII word.
        record: the ``.ot`` payload after the log-odds (numpy dtype), or None (occupancy only).
        columns: the per-leaf payload arrays.
        prune_on: columns that must be equal, besides the log-odds, for pruning.
        node_bytes: in-memory bytes of one node (OctoMap's ``memoryUsage`` model).
        label: column whose first slot is the most likely class, or None.
        colour: column holding ``uint8`` r, g, b, or None.
        encode: ``encode(columns, n) -> records``; default by field name.
        decode: ``decode(records) -> {column: array}``; default by field name.
        message_tree_id: the ``.ot`` id under which the tree writes its ROS node's full map
            (``octomap_full``) when that is not the saved file, or None. An id whose node
            layout the message has (an OctoMap tool must refuse it, not misread it).
        uses_semantics: the tree's update needs a segmenter's observation.
        description: one line for listings.
    """

    tree_id: str
    record: RecordFormat | None = None
    columns: tuple[Column, ...] = ()
    prune_on: tuple[str, ...] = ()
    node_bytes: int = 16
    label: str | None = None
    colour: str | None = None
    encode: Encoder | None = None
    decode: Decoder | None = None
    message_tree_id: str | None = None
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
        if self.message_tree_id is not None and not _ID.fullmatch(self.message_tree_id):
            raise InvalidDataError(f"node type {self.tree_id}: message_tree_id must be one "
                                   f"ASCII identifier, got {self.message_tree_id!r}")

    @property
    def column_names(self) -> tuple[str, ...]:
        return self._names

    def __reduce__(self) -> tuple[Callable[[str], NodeType], tuple[str]]:
        """A registered node type pickles as its id (its rules may be lambdas or closures), so
        an updater holding one can cross a process boundary."""
        if not NODE_TYPES.holds(self):
            raise TypeError(f"node type {self.tree_id!r} is not registered: only registered node "
                            f"types pickle (by their id)")
        return (_registered, (self.tree_id,))

    def to_record(self, columns: Mapping[str, np.ndarray], n: int) -> np.ndarray | None:
        """The payload records of ``n`` leaves from their columns (None without a record)."""
        if self.record is None:
            return None
        if self.encode is not None:
            return self.encode(columns, n)
        record = self._default_codec()
        if record.names is None:
            return np.asarray(columns[self._names[0]]).astype(record.base)
        rec: npt.NDArray[np.void] = np.empty(n, dtype=record.newbyteorder("="))
        for name in record.names:
            rec[name] = columns[name]
        return rec

    def from_record(self, record: np.ndarray) -> dict[str, np.ndarray]:
        """The columns held in ``record`` (inverse of :meth:`to_record`)."""
        if self.decode is not None:
            return dict(self.decode(record))
        layout = self._default_codec()
        if layout.names is None:
            return {self._names[0]: record}
        fields: npt.NDArray[np.void] = record
        return {name: fields[name] for name in layout.names}

    def _default_codec(self) -> RecordFormat:
        """The record, checked for the default encode/decode: record fields named like columns,
        or a plain record and one column."""
        if self.record is None:
            raise InvalidDataError(f"node type {self.tree_id} has no payload record")
        fields = self.record.names or ()
        if fields and not set(fields) <= set(self._names):
            raise InvalidDataError(
                f"node type {self.tree_id}: record fields {list(fields)} are not all columns "
                f"({', '.join(self._names) or 'none'}); give it encode and decode")
        if not fields and len(self._names) != 1:
            raise InvalidDataError(f"node type {self.tree_id}: a plain record needs exactly one "
                                   f"column, or encode and decode")
        return self.record


BUILTIN_NODE_MODULES: Mapping[str, str] = {
    "MultiClassBayesOcTree": "evsmap.mapping.mcb_nodes",
    "MultiClassBayesGeneratorOcTree": "evsmap.mapping.mcb_nodes",
    "SSMISemanticOcTreeMessage": "evsmap.mapping.mcb_nodes",
}
"""evsmap's own node types beyond OctoMap's, by ``.ot`` id: the module that registers each (data
and codec only, no kernels), imported when the id is first asked for, so that reading a file
needs no updater imported first."""


class NodeTypeRegistry:
    """Node types by ``.ot`` id; ``builtins`` (id -> module) are registered on first use."""

    def __init__(self, builtins: Mapping[str, str] | None = None) -> None:
        self._types: dict[str, NodeType] = {}
        self._builtins = dict(builtins or {})

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
        """The node type with id ``tree_id`` (a built-in one's module imported first).

        Raises:
            UnknownNameError: naming the known ids.
        """
        self._load(tree_id)
        try:
            return self._types[tree_id]
        except KeyError:
            raise UnknownNameError(f"unknown tree id {tree_id!r} (known: "
                                   f"{', '.join(self.names())}; a plug-in's node type is known "
                                   f"once its module is imported)") from None

    def _load(self, tree_id: str) -> None:
        """Import the module of built-in ``tree_id`` if it is not registered yet."""
        if tree_id not in self._types and tree_id in self._builtins:
            importlib.import_module(self._builtins[tree_id])

    def holds(self, node_type: NodeType) -> bool:
        """Whether ``node_type`` itself is the one registered under its id."""
        return self._types.get(node_type.tree_id) is node_type

    def names(self) -> list[str]:
        """The ids registered and the built-in ones."""
        return sorted(set(self._types) | set(self._builtins))

    def __contains__(self, tree_id: object) -> bool:
        return tree_id in self._types or tree_id in self._builtins

    def __iter__(self) -> Iterator[NodeType]:
        for tree_id in self._builtins:
            self._load(tree_id)
        return iter(list(self._types.values()))


NODE_TYPES = NodeTypeRegistry(BUILTIN_NODE_MODULES)
"""Every node type evsmap can read, by ``.ot`` id."""


def _registered(tree_id: str) -> NodeType:
    """The registered node type ``tree_id`` (unpickling)."""
    return NODE_TYPES.get(tree_id)


# --------------------------------------------------------------------------- OctoMap's own

#: Payload layout of a ``ColorOcTreeNode`` after its float: ``uint8`` r, g, b.
COLOR_FORMAT = np.dtype((np.uint8, (3,)))


OCTREE = NODE_TYPES.add(NodeType(
    "OcTree", description="OctoMap OcTree: float log-odds (5 B a node in .ot)"))
"""OctoMap's occupancy-only tree."""

COLOR_OCTREE = NODE_TYPES.add(NodeType(
    "ColorOcTree", record=COLOR_FORMAT, columns=(Column("rgb", np.uint8, (3,), fill=255),),
    colour="rgb", description="OctoMap ColorOcTree: log-odds + averaged r, g, b (8 B a node in "
                              ".ot); white = no colour"))
"""OctoMap's ``ColorOcTreeNode``: log-odds and r, g, b (white, 255/255/255, is "no colour");
pruning ignores colour. Its tree's rules (``averageNodeColor``, inner and pruned colours) are
:class:`evsmap.updaters.orgb.ORGBMap`'s."""
