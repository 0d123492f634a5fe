"""semantic_slam's node types (``.ot`` ids ``SemanticSlamOcTreeBayes`` /
``SemanticSlamOcTreeMax``) and its class colours, without the compiled node pool, so that
loading the plug-ins registers the types (and ``.ot`` files of them read by id) without
compiling anything.

The full ``.ot`` record is the node pool's state: colour, the packed class colours (PASCAL VOC
colours ``0x00RRGGBB``, semantic_slam keeps classes as colours) and their confidences. The leaf
view of :class:`baselines.semantic_slam.SemanticSlamMap` holds the colour, the packed colours and
the classes they are the colours of. A node is 48 B (Bayesian) or 32 B (max) in semantic_slam's
memory; its published file (:meth:`baselines.semantic_slam.SemanticSlamMap.published_file`) is a
``ColorOcTree`` with the top class colour.
"""

from __future__ import annotations

import numpy as np

from evsmap.mapping.generator import WHITE, pack_rgb, unpack_rgb, voc_colormap
from evsmap.mapping.node_type import NODE_TYPES, Column, NodeType

__all__ = ["FUSION_RULES", "NODE_TYPES_BY_RULE", "WHITE", "pack_rgb", "unpack_rgb", "voc_colormap"]

FUSION_RULES = ("bayes", "max")


def _node_type(rule: str) -> NodeType:
    slots = 3 if rule == "bayes" else 1
    return NODE_TYPES.add(NodeType(
        "SemanticSlamOcTreeBayes" if rule == "bayes" else "SemanticSlamOcTreeMax",
        record=np.dtype([("rgb", "u1", (3,)), ("colors", "<u4", (slots,)),
                         ("conf", "<f4", (slots,))]),
        columns=(Column("rgb", np.uint8, (3,), fill=255),
                 Column("sem_colors", np.uint32, (slots,), fill=WHITE),
                 Column("sem_classes", np.int16, (slots,), fill=-1)),
        # semantic_slam's node in RAM: a max node 32 B, a Bayesian node 48 B
        node_bytes=48 if rule == "bayes" else 32,
        label="sem_classes", colour="rgb", uses_semantics=True,
        description=f"[14] semantic_slam's node, {rule} fusion: RGB + {slots} x (packed class "
                    f"colour, conf)"))


NODE_TYPES_BY_RULE = {rule: _node_type(rule) for rule in FUSION_RULES}
"""semantic_slam's node types: the full ``.ot`` record is the node pool's state (colour, packed
class colours, confidences); the leaf view (``map``) holds the colour, the packed colours and
the classes they are the VOC colours of."""
