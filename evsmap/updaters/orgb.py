"""``orgb`` - ORGBMap: OctoMap occupancy with the RGB colour of the points averaged per voxel,
as OctoMap's ``ColorOcTree`` (EVSMaP Table IV's colour-only baseline row).

The node type is OctoMap's own :data:`~evsmap.mapping.node_type.COLOR_OCTREE`: per frame, each
hit voxel's colour becomes the ``ColorOcTree::averageNodeColor`` of its stored colour and the
mean colour of the frame's points in it (the first colour is copied); pruning ignores colour, an
inner node's colour is the average of its children's (``updateInnerOccupancy``). Files: ``.ot``
is a byte-compatible ``ColorOcTree``, ``.bt`` the occupancy only.
"""

from __future__ import annotations

from evsmap.mapping.node_type import COLOR_OCTREE
from evsmap.registry import UPDATERS
from evsmap.updaters.base import OctreeUpdater


class ORGBMap(OctreeUpdater):
    """Colour occupancy octree (OctoMap's ``ColorOcTree``)."""

    name = "orgb"
    node_type = COLOR_OCTREE


@UPDATERS.register("orgb", description="ORGBMap: OctoMap occupancy + averaged RGB "
                                       "(ColorOcTree), EVSMaP Table IV")
def orgb(*, resolution: float = 0.05, max_range: float = 5.0, discretize: bool = True,
         prob_hit: float = 0.7, prob_miss: float = 0.4, clamp_min: float = 0.1192,
         clamp_max: float = 0.971) -> ORGBMap:
    return ORGBMap(resolution=resolution, max_range=max_range, discretize=discretize,
                   prob_hit=prob_hit, prob_miss=prob_miss, clamp_min=clamp_min,
                   clamp_max=clamp_max)
