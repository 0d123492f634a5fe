"""``multiclass-bayes`` - EVSMaP's volumetric-semantic map (Section III-B, eqs. 5-10, Alg. 1).

Each leaf holds eq. 5's log-odds vector as SSMI keeps it (:class:`evsmap.mapping.fusion.MCBState`):
the 3 most likely classes with log-odds against free, plus "others", in ``float32``. Per frame
(the defaults, the paper's method):

* **Eq. 7 on every observed leaf.** A voxel the frame's rays traverse gets eq. 9's free case,
  ``phi`` on every entry (SSMI ``fuseObsFree``); a voxel holding end points gets one occupied
  observation with its points' majority class (the top class of their mean top-k
  distribution): ``psi`` to that class, ``phi`` to the rest, a new class entering from others
  (SSMI ``fuseObs`` / ``initSemantics``). Evidence accumulates to the clamps (+-9.21).
* **Occupancy from the class vector** (``occupancy="semantic"``): a leaf's occupancy log-odds is
  ``log(exp(others) + sum_i exp(l_i))``, the log-odds of "any class" against free (class 0 of
  eq. 5), so it is occupied exactly when ``p(free) < 0.5`` - OctoMap's threshold 0.5. A voxel
  without classes keeps its occupancy in ``others``, floored at OctoMap's clamping minimum as
  SSMI does (free space saturates and prunes).
* **Algorithm 1 where two nodes merge**: inner nodes take their children's states merged
  pairwise (:func:`~evsmap.mapping.fusion.fold_algorithm1`, theta = 0.6); 8 identical children
  are pruned into one node.

Options keep the alternatives measurable: ``leaf_update="average"`` merges a per-frame local
map into each leaf with Algorithm 1 (evsmap's earlier reading), ``pairing="ssmi"`` pairs a
class held by one node with the other node's punished others, ``occupancy="octomap"`` keeps
OctoMap's separate hit/miss log-odds. The ``.ot`` node payload is the full state (layout in
``docs/mapping.md``), so a saved map reloads into the same state
(:func:`load_multiclass_bayes`).

The node (:data:`NODE_TYPE`, ``.ot`` id ``MultiClassBayesOcTree``: columns, record, pruning) is
declared in :mod:`evsmap.mapping.mcb_nodes`; the tree's rules (the frame update, Algorithm 1 on
inner nodes) are :class:`MultiClassBayesMap`'s methods, its options one :class:`MCBRule`.
"""

from __future__ import annotations

from dataclasses import dataclass
from os import PathLike
from typing import Any

import numpy as np

from evsmap.data import SemanticObservation
from evsmap.errors import InvalidDataError
from evsmap.mapping import fusion
from evsmap.mapping.front_end import DirectScan, GroupedHits
from evsmap.mapping.fusion import MCBState
from evsmap.mapping.mcb_kernel import frame_update
from evsmap.mapping.mcb_nodes import (
    EMPTY_ID,
    MCB_NODE,
    MCB_RECORD,
    MCB_TREE_ID,
    encode_mcb,
    from_ids,
)
from evsmap.mapping.node_type import RecordFormat
from evsmap.mapping.occupancy import OccupancyMap
from evsmap.updaters.base import OctreeUpdater

__all__ = ["EMPTY_ID", "LEAF_UPDATES", "MAX_RESTORE_VOXELS", "NODE_TYPE", "OCCUPANCIES",
           "PAYLOAD_FORMAT", "TREE_ID", "MCBRule", "MultiClassBayesMap", "load_multiclass_bayes"]

PAYLOAD_FORMAT = MCB_RECORD
"""The node's ``.ot`` payload (:data:`evsmap.mapping.mcb_nodes.MCB_RECORD`)."""
TREE_ID = MCB_TREE_ID
NODE_TYPE = MCB_NODE
LEAF_UPDATES = ("bayes", "average")
OCCUPANCIES = ("semantic", "octomap")


@dataclass(frozen=True)
class MCBRule:
    """The options of the multi-class Bayesian update, as the frame kernel takes them.

    Attributes:
        psi, phi: eq. 9's log-odds steps (hit, miss).
        theta: Algorithm 1's punishment value.
        empty_floor: the floor of ``others`` on a voxel without classes (OctoMap's clamping
            minimum).
        leaf_update, pairing, occupancy: :class:`MultiClassBayesMap`'s variants.
    """

    psi: float
    phi: float
    theta: float
    empty_floor: float
    leaf_update: str
    pairing: str
    occupancy: str


@dataclass(frozen=True)
class MCBLeaves:
    """The map's columns the frame kernel writes: class slots, their log-odds, others and the
    occupancy log-odds (views into the leaf map)."""

    classes: np.ndarray
    class_logodds: np.ndarray
    others: np.ndarray
    occupancy: np.ndarray

    @classmethod
    def of(cls, leaves: OccupancyMap) -> MCBLeaves:
        return cls(leaves.payload("classes"), leaves.payload("class_logodds"),
                   leaves.payload("others"), leaves.logodds_for_writing())


def compiled_update(leaves: MCBLeaves, free: np.ndarray, hits: GroupedHits,
                    observation: SemanticObservation, rule: MCBRule) -> bool:
    """One frame's semantics by the compiled kernel (:mod:`evsmap.mapping.mcb_kernel`): rays
    on the ``free`` leaves, one observation per hit voxel; False (nothing done) where the kernel
    does not apply: numba missing, an empty observation or a local map beyond
    :data:`fusion.DENSE_LIMIT`."""
    if frame_update is None:
        return False
    span = int(observation.classes.max()) + 1 if observation.classes.size else 0
    if not (0 < span and len(hits.voxels) * span <= fusion.DENSE_LIMIT):
        return False
    k = observation.k
    frame_update(
        leaves.classes, leaves.class_logodds, leaves.others, leaves.occupancy, free,
        hits.voxels, hits.local, hits.pixels, observation.classes.reshape(-1, k),
        observation.probs.reshape(-1, k), span, rule.psi, rule.phi, rule.theta,
        fusion.MIN_LOGODDS, fusion.MAX_LOGODDS, fusion.PROB_MIN, rule.empty_floor,
        rule.leaf_update == "bayes", rule.pairing == "printed", rule.occupancy == "semantic")
    return True


class MultiClassBayesMap(OctreeUpdater):
    """EVSMaP's multi-class Bayesian semantic octree (node type :data:`NODE_TYPE`).

    Args:
        psi: log-odds added to the observed class (eq. 9, phi+ of the occupied case).
        phi: log-odds added on a miss (eq. 9, phi-) and to the other entries on a hit.
        theta: Algorithm 1's punishment value.
        leaf_update: ``"bayes"`` (eq. 7: one additive observation per observed leaf and frame,
            the paper's) or ``"average"`` (the frame's local node merged into the leaf with
            Algorithm 1).
        pairing: Algorithm 1's pairing of a class held by one node only with a punished others:
            ``"printed"`` (the holding node's own, as printed) or ``"ssmi"`` (the other node's).
        occupancy: ``"semantic"`` (the leaf's occupancy log-odds derived from its class vector,
            eq. 5) or ``"octomap"`` (OctoMap's separate hit/miss log-odds).
        (other arguments: :class:`~evsmap.updaters.tree_map.OctreeMap`)
    """

    semantics_within_range = True

    name = "multiclass-bayes"
    node_type = NODE_TYPE

    def __init__(self, *, psi: float = fusion.PSI, phi: float = fusion.PHI,
                 theta: float = fusion.THETA, leaf_update: str = "bayes",
                 pairing: str = "printed", occupancy: str = "semantic", **kwargs: Any) -> None:
        for option, value, known in (("leaf_update", leaf_update, LEAF_UPDATES),
                                     ("pairing", pairing, fusion.PAIRINGS),
                                     ("occupancy", occupancy, OCCUPANCIES)):
            if value not in known:
                raise InvalidDataError(f"multiclass-bayes: {option} must be one of "
                                       f"{', '.join(known)}; got {value!r}")
        self.psi, self.phi, self.theta = float(psi), float(phi), float(theta)
        self.leaf_update, self.pairing, self.occupancy = leaf_update, pairing, occupancy
        super().__init__(**kwargs)
        # a voxel without classes keeps its occupancy in ``others``: floored where OctoMap
        # clamps (SSMI's fuseObsFree on such voxels)
        self.empty_floor = float(self.params.clamp_min_logodds)

    @property
    def rule(self) -> MCBRule:
        """The update's options as one bundle."""
        return MCBRule(self.psi, self.phi, self.theta, self.empty_floor, self.leaf_update,
                       self.pairing, self.occupancy)

    def state(self, index: np.ndarray | slice = slice(None)) -> MCBState:
        m = self.map
        return MCBState(m.payload("classes")[index], m.payload("class_logodds")[index],
                        m.payload("others")[index])

    def store(self, index: np.ndarray, state: MCBState) -> None:
        """Write ``state`` into the leaves ``index``."""
        m = self.map
        m.payload("classes")[index] = state.classes
        m.payload("class_logodds")[index] = state.logodds
        m.payload("others")[index] = state.others

    def check_classes(self, observation: SemanticObservation) -> None:
        """Class ids are stored in one byte (255 = empty slot).

        Raises:
            InvalidDataError: the observation's label set has more than 255 classes.
        """
        if observation.num_classes > EMPTY_ID:
            raise InvalidDataError(f"multiclass-bayes stores class ids in one byte: at most "
                                   f"{EMPTY_ID} classes, got {observation.num_classes}")

    # -- the tree's rules -------------------------------------------------------------------
    def update_payload(self, scan: DirectScan) -> None:
        """A frame's semantics on the leaves it observed: the compiled kernel
        (:func:`compiled_update`), or the numpy reference with ``kernels="reference"``."""
        observation = scan.observation
        assert observation is not None  # uses_semantics: integrate checked it
        self.check_classes(observation)
        if self.kernels == "compiled":
            hits = self.endpoint_voxels(scan.points)
            if compiled_update(MCBLeaves.of(self.map), scan.occupancy.free_index, hits,
                               observation, self.rule):
                return
        self.update_reference(scan, observation)

    def update_reference(self, scan: DirectScan, observation: SemanticObservation) -> None:
        """The reference implementation (numpy, whole arrays)."""
        semantic = self.occupancy == "semantic"
        # rays: eq. 9's free case on the traversed voxels (with OctoMap occupancy, only those
        # holding classes have a semantic state to lower)
        free = scan.occupancy.free_index
        if not semantic and free.size:
            free = free[self.map.payload("classes")[free, 0] >= 0]
        if free.size:
            self.store(free, fusion.mcb_miss(self.state(free), phi=self.phi,
                                             empty_min_logodds=self.empty_floor))
        # end points: the frame's node per voxel, from its points' top-k
        pixels, voxels, local_index = self.endpoint_voxels(scan.points)
        if voxels.size:
            self._observe(voxels, local_index, observation.classes.reshape(-1, observation.k)[
                pixels], observation.probs.reshape(-1, observation.k)[pixels])
        if semantic:
            touched = np.concatenate([free, voxels])
            self.map.logodds_for_writing()[touched] = fusion.mcb_occupancy(self.state(touched))

    def _observe(self, voxels: np.ndarray, local_index: np.ndarray, classes: np.ndarray,
                 probs: np.ndarray) -> None:
        """The hit voxels' update from their points' top-k (numpy)."""
        local = fusion.build_local(local_index, classes, probs, len(voxels), hit=self.psi)
        current = self.state(voxels)
        if self.leaf_update == "bayes":  # eq. 7: one observation, the majority class
            self.store(voxels, fusion.mcb_observe(current, local.classes[:, 0], psi=self.psi,
                                                  phi=self.phi))
        else:  # the local node merged with Algorithm 1; a first observation takes it
            known = current.has_semantics
            merged = fusion.merge_algorithm1(current.take(known), local.take(known),
                                             self.theta, pairing=self.pairing)
            self.store(voxels[known], merged)
            self.store(voxels[~known], local.take(~known))

    def inner_payload(self, children: np.ndarray, group: np.ndarray,
                      n_groups: int) -> np.ndarray:
        """Algorithm 1 where nodes merge: an inner node's state is its children's, merged
        pairwise in child order (:func:`~evsmap.mapping.fusion.fold_algorithm1`)."""
        state = MCBState(from_ids(children["classes"]), children["logodds"],
                         children["others"])
        merged = fusion.fold_algorithm1(state, group, n_groups, self.theta,
                                        pairing=self.pairing)
        return encode_mcb({"classes": merged.classes, "class_logodds": merged.logodds,
                           "others": merged.others}, n_groups)


MAX_RESTORE_VOXELS = 10_000_000
"""Finest voxels a restored map may hold (the file's pruned leaves expanded): about 110 bytes
each while restoring, so ~1.1 GB; a small file whose coarse leaves claim more is refused."""


def load_multiclass_bayes(path: str | PathLike[str], **kwargs: Any) -> MultiClassBayesMap:
    """A :class:`MultiClassBayesMap` restored from its ``.ot`` file (mapping can continue);
    ``kwargs`` are the map's options.

    Raises:
        DataFormatError: unreadable or corrupt file, another tree id, or leaves covering more
            than :data:`MAX_RESTORE_VOXELS` finest voxels (names the file).
    """
    from evsmap.errors import DataFormatError
    from evsmap.mapping.keys import TREE_DEPTH
    from evsmap.mapping.octree_io import read_ot

    formats: dict[str, RecordFormat] = {TREE_ID: PAYLOAD_FORMAT}
    saved = read_ot(path, payload_format=formats)
    resolution, tree = saved.resolution, saved.tree
    depth = tree.leaves()[0].astype(np.float64)
    voxels = float(np.sum(8.0 ** (TREE_DEPTH - depth)))
    if voxels > MAX_RESTORE_VOXELS:
        raise DataFormatError(f"{path}: its {len(depth)} leaves cover {voxels:.3g} finest voxels, "
                              f"more than the {MAX_RESTORE_VOXELS:.3g} a map is restored with")
    try:
        return MultiClassBayesMap(resolution=resolution, **kwargs).restore(path)
    except DataFormatError:
        raise
    except InvalidDataError as exc:  # a well-formed file whose map cannot be rebuilt
        raise DataFormatError(f"{path}: not a map this updater can restore ({exc})") from None
