"""``orgb`` - ORGBMap: OctoMap occupancy with the RGB colour of the points averaged per voxel,
as OctoMap's ``ColorOcTree`` (EVSMaP Table IV's colour-only baseline row).

The node type is OctoMap's own :data:`~evsmap.mapping.node_type.COLOR_OCTREE`; the rules are
``ColorOcTree``'s, as methods of the tree: per frame, each hit voxel's colour becomes the
``ColorOcTree::averageNodeColor`` of its stored colour and the mean colour of the frame's points
in it (the first colour is copied); pruning ignores colour, an inner node's colour is the average
of its children's (``updateInnerOccupancy``), a pruned node's as ``ColorOcTree::pruneNode`` sets
it. Files: ``.ot`` is a byte-compatible ``ColorOcTree``, ``.bt`` the occupancy only. Registered as
``orgb`` by :mod:`evsmap.updaters.registered`.
"""

from __future__ import annotations

import numpy as np

from evsmap.mapping.front_end import DirectScan
from evsmap.mapping.fusion.colour import average_frame_colours
from evsmap.mapping.node_type import COLOR_OCTREE
from evsmap.mapping.tree import octomap_colour_average, octomap_colour_prune
from evsmap.updaters.base import OctreeUpdater


class ORGBMap(OctreeUpdater):
    """Colour occupancy octree (OctoMap's ``ColorOcTree``)."""

    name = "orgb"
    node_type = COLOR_OCTREE

    def update_payload(self, scan: DirectScan) -> None:
        """``ColorOcTree::averageNodeColor`` of every hit voxel with its points' mean colour."""
        pixels, voxels, local = self.endpoint_voxels(scan.points)
        if voxels.size:
            average_frame_colours(self.map.payload("rgb"), scan.frame.colors(), pixels, voxels,
                                  local)

    def inner_payload(self, children: np.ndarray, group: np.ndarray,
                      n_groups: int) -> np.ndarray:
        """The average of the children's set colours (``updateInnerOccupancy``)."""
        return octomap_colour_average(children, group, n_groups)

    def pruned_payload(self, children: np.ndarray, group: np.ndarray,
                       n_groups: int) -> np.ndarray:
        """``ColorOcTree::pruneNode``'s colour."""
        return octomap_colour_prune(children, group, n_groups)
