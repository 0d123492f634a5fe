"""Per-voxel fusion rules of the map updaters, vectorised over arrays of voxels, one concern per
module:

* :mod:`~evsmap.mapping.fusion.slots` - the semantic slots (3 classes, empty = -1) the rules
  share: matching, stable ranking, padding;
* :mod:`~evsmap.mapping.fusion.colour` - OctoMap ``ColorOcTree``'s colour rules (leaf averaging,
  inner-node averages);
* :mod:`~evsmap.mapping.fusion.mcb` - EVSMaP's multi-class Bayesian node state and its
  per-observation rules (eqs. 5-9, SSMI ``fuseObs`` / ``fuseObsFree``);
* :mod:`~evsmap.mapping.fusion.merge` - merging two such nodes: Algorithm 1 (eq. 10, theta) and
  SSMI's ``semanticFusion``, and the inner-node fold;
* :mod:`~evsmap.mapping.fusion.local_map` - the local map of one frame (one node per voxel).

semantic_slam's own rules (the "traditional" max and Bayesian fusion of [14]) are used by the
baseline only and live in ``baselines.semantic_slam_fusion``.

Every function is pure: it takes struct-of-arrays states for M voxels and returns new arrays; no
Python loop runs per voxel (loops over the 3 semantic slots only). This package re-exports the
public names of its modules, so ``from evsmap.mapping import fusion; fusion.mcb_hit(...)``
works.
"""

from __future__ import annotations

from evsmap.mapping.fusion.colour import (
    WHITE,
    average_color,
    average_frame_colours,
    average_node_color,
    color_is_set,
    integrate_color,
    mean_per_voxel,
)
from evsmap.mapping.fusion.local_map import DENSE_LIMIT, build_local
from evsmap.mapping.fusion.mcb import (
    ALPHA,
    BETA,
    MAX_LOGODDS,
    MIN_LOGODDS,
    PHI,
    PROB_MAX,
    PROB_MIN,
    PSI,
    MCBState,
    mcb_hit,
    mcb_miss,
    mcb_observe,
    mcb_occupancy,
    mcb_probabilities,
)
from evsmap.mapping.fusion.merge import (
    PAIRINGS,
    THETA,
    fold_algorithm1,
    merge_algorithm1,
    merge_ssmi,
)
from evsmap.mapping.fusion.slots import EMPTY, SLOTS

__all__ = [
    "ALPHA", "BETA", "DENSE_LIMIT", "EMPTY", "MAX_LOGODDS", "MIN_LOGODDS", "PAIRINGS", "PHI",
    "PROB_MAX", "PROB_MIN", "PSI", "SLOTS", "THETA", "WHITE", "MCBState", "average_color",
    "average_frame_colours", "average_node_color", "build_local", "color_is_set",
    "fold_algorithm1", "integrate_color", "mcb_hit", "mcb_miss", "mcb_observe", "mcb_occupancy",
    "mcb_probabilities", "mean_per_voxel", "merge_algorithm1", "merge_ssmi",
]
