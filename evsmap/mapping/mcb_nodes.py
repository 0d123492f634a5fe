"""The node types of EVSMaP's multi-class Bayesian map: data and codec, no rules and no kernels.

* :data:`MCB_NODE` (``.ot`` id ``MultiClassBayesOcTree``): the direct front end's node
  (:class:`evsmap.updaters.multiclass_bayes.MultiClassBayesMap`): eq. 5's log-odds vector as
  SSMI keeps it - the 3 most likely classes with log-odds against free, plus "others".
* :data:`GENERATOR_NODE` (``MultiClassBayesGeneratorOcTree``): the same state as SSMI's
  ``SemanticOcTreeNode`` keeps it on the generator front end
  (:class:`evsmap.updaters.mcb_generator.GeneratorMultiClassBayesMap`): colour, 3 class colours,
  their log-odds and others.
* :data:`MESSAGE_NODE` (``SSMISemanticOcTreeMessage``): SSMI's ``octomap_full`` message nodes,
  read only.

They are registered when this module is imported, which
:data:`evsmap.mapping.node_type.NODE_TYPES` does when one of their ids is first asked for (reading
an ``.ot`` file needs no updater imported).
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from evsmap.mapping import fusion
from evsmap.mapping.generator import WHITE, pack_rgb, voc_colormap
from evsmap.mapping.node_type import NODE_TYPES, Column, NodeType

__all__ = ["EMPTY_ID", "GENERATOR_NODE", "LOGINIT", "MCB_NODE", "MCB_RECORD", "MCB_TREE_ID",
           "MESSAGE_NODE", "MESSAGE_TREE_ID", "NODE_BYTES", "PUBLISHED", "RECORD", "TREE_ID",
           "colour_classes", "from_ids"]

# --------------------------------------------------------------------------- the direct node

MCB_RECORD = np.dtype([("classes", "u1", (3,)), ("logodds", "<f4", (3,)), ("others", "<f4")])
"""Per-node payload after the float32 occupancy log-odds in the ``.ot`` stream (19 bytes): class
ids (255 = empty slot) and the class and "others" log-odds, float32 as the map keeps them."""
EMPTY_ID = 255
MCB_TREE_ID = "MultiClassBayesOcTree"


def _to_ids(classes: np.ndarray) -> np.ndarray:
    """Class slots as the file stores them: ``uint8``, 255 for an empty slot."""
    return np.where(classes < 0, EMPTY_ID, classes)


def from_ids(ids: np.ndarray) -> np.ndarray:
    """Class slots as the map keeps them (``int16``, :data:`fusion.EMPTY` for an empty slot)
    from the file's ``uint8`` ids."""
    ids = ids.astype(np.int16)
    return np.where(ids == EMPTY_ID, fusion.EMPTY, ids)


def encode_mcb(columns: Mapping[str, np.ndarray], n: int) -> np.ndarray:
    """The ``.ot`` records of ``n`` leaves from the map's columns."""
    rec = np.empty(n, dtype=MCB_RECORD)
    rec["classes"] = _to_ids(columns["classes"])
    rec["logodds"] = columns["class_logodds"]
    rec["others"] = columns["others"]
    return rec


def _decode_mcb(record: np.ndarray) -> dict[str, np.ndarray]:
    return {"classes": from_ids(record["classes"]), "class_logodds": record["logodds"],
            "others": record["others"]}


MCB_NODE = NODE_TYPES.add(NodeType(
    MCB_TREE_ID, record=MCB_RECORD,
    columns=(Column("classes", np.int16, (3,), fill=fusion.EMPTY),
             Column("class_logodds", np.float32, (3,), fill=0),
             Column("others", np.float32, (), fill=0)),
    prune_on=("classes", "class_logodds", "others"),
    # OctoMap node: 4 B log-odds + children pointer (8 B) + this payload, 8-byte aligned
    node_bytes=-(-(4 + 8 + MCB_RECORD.itemsize) // 8) * 8,
    label="classes", encode=encode_mcb, decode=_decode_mcb, uses_semantics=True,
    description="EVSMaP multi-class Bayesian node: 3 classes + log-odds + others"))
"""EVSMaP's node. Published file = the full one: the node "maintain[s] only the probabilities of
the three most likely semantic classes ... all other classes are consolidated into an others
class": 3 class ids, their 3 log-odds and others, which is exactly the full payload."""

# --------------------------------------------------------------------------- SSMI's node

TREE_ID = "MultiClassBayesGeneratorOcTree"

LOGINIT = np.float32(-0.1)
"""SSMI's initial semantic log-odds (``SemanticsLogOdds``: every slot and others start here)."""

RECORD = np.dtype([("rgb", "u1", (3,)), ("colors", "<u4", (3,)), ("logodds", "<f4", (3,)),
                   ("others", "<f4")])
"""The ``full`` file's node payload after the float value: the node's colour, its 3 class
colours (``0x00RRGGBB``, white = unset), their log-odds and others."""

SEMANTICS_STRUCT = np.dtype([("color", "u1", (3,)), ("pad", "u1"), ("logodds", "<f4")])
PUBLISHED = np.dtype([("color", "u1", (3,)), ("slots", SEMANTICS_STRUCT, (3,)),
                      ("others", "<f4")])
"""SSMI's ``writeData`` with the semantics, after the value: ``Color`` (3 bytes) and
``sizeof(SemanticsLogOdds)`` = 3 x ``ColorWithLogOdds`` (3 colour bytes, 1 padding byte, float)
+ float others = 28 bytes: the nodes of its ``octomap_full`` message."""

MESSAGE_TREE_ID = "SSMISemanticOcTreeMessage"
"""The ``.ot`` id of SSMI's message nodes as evsmap writes them (SSMI itself never writes them
to a file, and the id it sends, ``ColorOcTree``, has another node layout)."""

NODE_BYTES = 48
"""``sizeof(SemanticOcTreeNode<SemanticsLogOdds>)`` on x86-64: children pointer 8, value 4,
colour 3, semantics 28 (4-aligned), two bools, padded to 8."""


def colour_classes(colours: np.ndarray, num_classes: int) -> np.ndarray:
    """Class ids of packed class colours under the VOC colour map; -1 for white and for colours
    that are no class's (an averaged colour)."""
    table = pack_rgb(voc_colormap(max(int(num_classes), 1)))
    order = np.argsort(table, kind="stable")
    sorted_table = table[order]
    c = np.asarray(colours, dtype=np.uint32)
    pos = np.clip(np.searchsorted(sorted_table, c), 0, len(table) - 1)
    return np.where(sorted_table[pos] == c, order[pos], -1).astype(np.int16)


def encode_generator(columns: Mapping[str, np.ndarray], n: int) -> np.ndarray:
    """The ``full`` file's records of ``n`` leaves from the map's columns."""
    rec = np.empty(n, dtype=RECORD)
    rec["rgb"] = columns["rgb"]
    rec["colors"] = columns["sem_colors"]
    rec["logodds"] = columns["class_logodds"]
    rec["others"] = columns["others"]
    return rec


def _decode_generator(record: np.ndarray) -> dict[str, np.ndarray]:
    colours = np.asarray(record["colors"], dtype=np.uint32)
    return {"rgb": record["rgb"], "sem_colors": colours, "class_logodds": record["logodds"],
            "others": record["others"], "classes": colour_classes(colours, 256)}


GENERATOR_NODE = NODE_TYPES.add(NodeType(
    TREE_ID, record=RECORD,
    columns=(Column("rgb", np.uint8, (3,), fill=255),
             Column("sem_colors", np.uint32, (3,), fill=WHITE),
             Column("class_logodds", np.float32, (3,), fill=LOGINIT),
             Column("others", np.float32, (), fill=LOGINIT),
             Column("classes", np.int16, (3,), fill=-1),
             Column("pruned_level", np.uint8, (), fill=0)),
    prune_on=("sem_colors", "class_logodds", "others"), node_bytes=NODE_BYTES,
    label="classes", colour="rgb", encode=encode_generator, decode=_decode_generator,
    message_tree_id=MESSAGE_TREE_ID, uses_semantics=True,
    description="EVSMaP's node as SSMI keeps it: colour + 3 x (class colour, log-odds) + others"))
"""SSMI's node with EVSMaP's update. Pruning compares ``prune_on`` except where the first child
is free (:meth:`~evsmap.updaters.mcb_generator.GeneratorMultiClassBayesMap.prune_columns`)."""

MESSAGE_NODE = NODE_TYPES.add(NodeType(
    MESSAGE_TREE_ID, record=PUBLISHED, node_bytes=NODE_BYTES,
    description="SSMI's octomap_full message nodes: value, top semantic colour, "
                "SemanticsLogOdds (read only: it restores no map)"))
