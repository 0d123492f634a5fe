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

The node type (:data:`NODE_TYPE`, ``.ot`` id ``MultiClassBayesOcTree``) holds all of this; the
updater class only adds the options and checks them.
"""

from __future__ import annotations

from os import PathLike

import numpy as np

from evsmap.data import Frame, SemanticObservation
from evsmap.mapping import fusion
from evsmap.mapping.fusion import MCBState
from evsmap.mapping.mcb_kernel import frame_update
from evsmap.mapping.node_type import NODE_TYPES, Column, NodeType
from evsmap.mapping.occupancy import ScanUpdate
from evsmap.updaters.base import FramePoints, OctreeUpdater

PAYLOAD_FORMAT = np.dtype([("classes", "u1", (3,)), ("logodds", "<f4", (3,)),
                           ("others", "<f4")])
"""Per-node payload after the float32 occupancy log-odds in the ``.ot`` stream (19 bytes): class
ids (255 = empty slot) and the class and "others" log-odds, float32 as the map keeps them."""
EMPTY_ID = 255
TREE_ID = "MultiClassBayesOcTree"
LEAF_UPDATES = ("bayes", "average")
OCCUPANCIES = ("semantic", "octomap")


def _to_ids(classes: np.ndarray) -> np.ndarray:
    """Class slots as the file stores them: ``uint8``, 255 for an empty slot."""
    return np.where(classes < 0, EMPTY_ID, classes)


def _from_ids(ids: np.ndarray) -> np.ndarray:
    ids = ids.astype(np.int16)
    return np.where(ids == EMPTY_ID, fusion.EMPTY, ids)


def _encode(columns, n: int) -> np.ndarray:
    rec = np.empty(n, dtype=PAYLOAD_FORMAT)
    rec["classes"] = _to_ids(columns["classes"])
    rec["logodds"] = columns["class_logodds"]
    rec["others"] = columns["others"]
    return rec


def _decode(record: np.ndarray) -> dict[str, np.ndarray]:
    return {"classes": _from_ids(record["classes"]), "class_logodds": record["logodds"],
            "others": record["others"]}


def _update(updater: MultiClassBayesMap, frame: Frame, points: FramePoints, update: ScanUpdate,
            observation: SemanticObservation) -> None:
    """A frame's semantics on the leaves it observed: the compiled kernel
    (:mod:`evsmap.mapping.mcb_kernel`), or the numpy reference with ``kernels="reference"``."""
    updater.check_classes(observation)
    if updater.kernels == "compiled" and frame_update is not None:
        pixels, voxels, local_index = updater.endpoint_voxels(points)
        span = int(observation.classes.max()) + 1 if observation.classes.size else 0
        if 0 < span and len(voxels) * span <= fusion.DENSE_LIMIT:
            k = observation.k
            m = updater.map
            frame_update(
                m.payload("classes"), m.payload("class_logodds"), m.payload("others"),
                m.logodds_for_writing(), update.free_index, voxels, local_index, pixels,
                observation.classes.reshape(-1, k), observation.probs.reshape(-1, k),
                span, updater.psi, updater.phi, updater.theta, fusion.MIN_LOGODDS,
                fusion.MAX_LOGODDS, fusion.PROB_MIN, updater.empty_floor,
                updater.leaf_update == "bayes", updater.pairing == "printed",
                updater.occupancy == "semantic")
            return
    _update_numpy(updater, points, update, observation)


def _update_numpy(updater: MultiClassBayesMap, points: FramePoints, update: ScanUpdate,
                  observation: SemanticObservation) -> None:
    """The reference implementation (numpy, whole arrays)."""
    semantic = updater.occupancy == "semantic"
    # rays: eq. 9's free case on the traversed voxels (with OctoMap occupancy, only those
    # holding classes have a semantic state to lower)
    free = update.free_index
    if not semantic and free.size:
        free = free[updater.map.payload("classes")[free, 0] >= 0]
    if free.size:
        updater._store(free, fusion.mcb_miss(updater.state(free), phi=updater.phi,
                                             empty_min_logodds=updater.empty_floor))
    # end points: the frame's node per voxel, from its points' top-k
    pixels, voxels, local_index = updater.endpoint_voxels(points)
    if voxels.size:
        classes = observation.classes.reshape(-1, observation.k)[pixels]
        probs = observation.probs.reshape(-1, observation.k)[pixels]
        local = fusion.build_local(local_index, classes, probs, len(voxels), hit=updater.psi)
        current = updater.state(voxels)
        if updater.leaf_update == "bayes":  # eq. 7: one observation, the majority class
            updater._store(voxels, fusion.mcb_observe(current, local.classes[:, 0],
                                                      psi=updater.psi, phi=updater.phi))
        else:  # the local node merged with Algorithm 1; a first observation takes it
            known = current.has_semantics
            merged = fusion.merge_algorithm1(current.take(known), local.take(known),
                                             updater.theta, pairing=updater.pairing)
            updater._store(voxels[known], merged)
            updater._store(voxels[~known], local.take(~known))
    if semantic:
        touched = np.concatenate([free, voxels])
        updater.map.logodds_for_writing()[touched] = fusion.mcb_occupancy(
            updater.state(touched))


def _inner(updater: MultiClassBayesMap, child_payload: np.ndarray, group: np.ndarray,
           n_groups: int) -> np.ndarray:
    """Algorithm 1 where nodes merge: an inner node's state is its children's, merged pairwise
    in child order (:func:`~evsmap.mapping.fusion.fold_algorithm1`)."""
    children = MCBState(_from_ids(child_payload["classes"]), child_payload["logodds"],
                        child_payload["others"])
    merged = fusion.fold_algorithm1(children, group, n_groups, updater.theta,
                                    pairing=updater.pairing)
    return _encode({"classes": merged.classes, "class_logodds": merged.logodds,
                    "others": merged.others}, n_groups)


NODE_TYPE = NODE_TYPES.add(NodeType(
    TREE_ID, record=PAYLOAD_FORMAT,
    columns=(Column("classes", np.int16, (3,), fill=fusion.EMPTY),
             Column("class_logodds", np.float32, (3,), fill=0),
             Column("others", np.float32, (), fill=0)),
    update=_update, inner=_inner, prune_on=("classes", "class_logodds", "others"),
    # OctoMap node: 4 B log-odds + children pointer (8 B) + this payload, 8-byte aligned
    node_bytes=-(-(4 + 8 + PAYLOAD_FORMAT.itemsize) // 8) * 8,
    label="classes", encode=_encode, decode=_decode, uses_semantics=True,
    description="EVSMaP multi-class Bayesian node: 3 classes + log-odds + others"))
"""EVSMaP's node. Published file = the full one: the node "maintain[s] only the probabilities of
the three most likely semantic classes ... all other classes are consolidated into an others
class": 3 class ids, their 3 log-odds and others, which is exactly the full payload."""


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
        (other arguments: :class:`~evsmap.updaters.base.OctreeUpdater`)
    """

    semantics_within_range = True

    name = "multiclass-bayes"
    node_type = NODE_TYPE

    def __init__(self, *, psi: float = fusion.PSI, phi: float = fusion.PHI,
                 theta: float = fusion.THETA, leaf_update: str = "bayes",
                 pairing: str = "printed", occupancy: str = "semantic", **kwargs) -> None:
        from evsmap.errors import InvalidDataError

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

    def state(self, index: np.ndarray | slice = slice(None)) -> MCBState:
        m = self.map
        return MCBState(m.payload("classes")[index], m.payload("class_logodds")[index],
                        m.payload("others")[index])

    def _store(self, index: np.ndarray, state: MCBState) -> None:
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
            from evsmap.errors import InvalidDataError

            raise InvalidDataError(f"multiclass-bayes stores class ids in one byte: at most "
                                   f"{EMPTY_ID} classes, got {observation.num_classes}")


MAX_RESTORE_VOXELS = 10_000_000
"""Finest voxels a restored map may hold (the file's pruned leaves expanded): about 110 bytes
each while restoring, so ~1.1 GB; a small file whose coarse leaves claim more is refused."""


def load_multiclass_bayes(path: str | PathLike[str], **kwargs) -> MultiClassBayesMap:
    """A :class:`MultiClassBayesMap` restored from its ``.ot`` file (mapping can continue);
    ``kwargs`` are the map's options.

    Raises:
        DataFormatError: unreadable or corrupt file, another tree id, or leaves covering more
            than :data:`MAX_RESTORE_VOXELS` finest voxels (names the file).
    """
    from evsmap.errors import DataFormatError, InvalidDataError
    from evsmap.mapping.keys import TREE_DEPTH
    from evsmap.mapping.octree_io import read_ot

    formats: dict[str, np.dtype] = {TREE_ID: PAYLOAD_FORMAT}
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
