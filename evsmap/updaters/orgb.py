"""``orgb`` - ORGBMap: OctoMap occupancy with the RGB colour of the points averaged per voxel,
as OctoMap's ``ColorOcTree`` (EVSMaP Table IV's colour-only baseline row)."""

from __future__ import annotations

import numpy as np

from evsmap.data import Frame, SemanticObservation
from evsmap.mapping.occupancy import ScanUpdate
from evsmap.mapping.tree import Tree, build_color_tree
from evsmap.registry import UPDATERS
from evsmap.updaters.base import FramePoints, OctreeUpdater


class ORGBMap(OctreeUpdater):
    """Colour occupancy octree.

    Per frame, each hit voxel's colour becomes the ``ColorOcTree::averageNodeColor`` of its
    stored colour and the mean colour of the frame's points in it (the first colour is copied);
    pruning ignores colour, an inner node's colour is the average of its children's
    (``ColorOcTree``'s ``updateInnerOccupancy``). Files: ``.ot`` is a byte-compatible
    ``ColorOcTree``, ``.bt`` the occupancy only.
    """

    name = "orgb"
    tree_type = "ColorOcTree"

    def _init_payloads(self) -> None:
        self.map.add_payload("rgb", np.uint8, (3,), fill=255)  # white = no colour (OctoMap)

    def _update_payloads(self, frame: Frame, points: FramePoints, update: ScanUpdate,
                         observation: SemanticObservation | None) -> None:
        pixels, voxels, local = self.endpoint_voxels(points)
        if voxels.size:
            self._average_colours(frame, pixels, voxels, local)

    def _set_payload_record(self, record: np.ndarray | None) -> None:
        if record is not None:
            self.map.payload("rgb")[:] = record

    def tree(self) -> Tree:
        return build_color_tree(self.map.codes, np.asarray(self.map.logodds),
                                self.map.payload("rgb"))


@UPDATERS.register("orgb", description="ORGBMap: OctoMap occupancy + averaged RGB "
                                       "(ColorOcTree), EVSMaP Table IV")
def orgb(*, resolution: float = 0.05, max_range: float = 5.0, discretize: bool = True,
         prob_hit: float = 0.7, prob_miss: float = 0.4, clamp_min: float = 0.1192,
         clamp_max: float = 0.971) -> ORGBMap:
    return ORGBMap(resolution=resolution, max_range=max_range, discretize=discretize,
                   prob_hit=prob_hit, prob_miss=prob_miss, clamp_min=clamp_min,
                   clamp_max=clamp_max)
