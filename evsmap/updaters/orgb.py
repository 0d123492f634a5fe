"""``orgb`` - ORGBMap: OctoMap occupancy with the RGB colour of the points averaged per voxel,
as OctoMap's ``ColorOcTree`` (EVSMaP Table IV's colour-only baseline row).

The node type is OctoMap's own :data:`~evsmap.mapping.node_type.COLOR_OCTREE`: per frame, each
hit voxel's colour becomes the ``ColorOcTree::averageNodeColor`` of its stored colour and the
mean colour of the frame's points in it (the first colour is copied); pruning ignores colour, an
inner node's colour is the average of its children's (``updateInnerOccupancy``). Files: ``.ot``
is a byte-compatible ``ColorOcTree``, ``.bt`` the occupancy only. Registered as ``orgb`` by
:mod:`evsmap.updaters.registered`.
"""

from __future__ import annotations

from evsmap.mapping.node_type import COLOR_OCTREE
from evsmap.updaters.base import OctreeUpdater


class ORGBMap(OctreeUpdater):
    """Colour occupancy octree (OctoMap's ``ColorOcTree``)."""

    name = "orgb"
    node_type = COLOR_OCTREE
