"""``multiclass-bayes`` - EVSMaP's volumetric-semantic map (Section III-B, eqs. 5-10, Alg. 1).

Occupancy follows OctoMap (hit/miss log-odds, clamping), so the geometry is directly comparable
with every other row of Table IV. Each leaf also holds the multi-class log-odds state of SSMI's
lineage (:class:`evsmap.mapping.fusion.MCBState`): the 3 most likely classes with log-odds
against free, plus "others". A frame is first built as a local map (one node per hit voxel,
:func:`~evsmap.mapping.fusion.build_local`: the mean of its points' top-3 distributions) and
merged into the global map with Algorithm 1 (:func:`~evsmap.mapping.fusion.merge_algorithm1`,
punishment theta = 0.6); a voxel seen for the first time takes the local node. Voxels a ray
passes through have their semantic log-odds lowered by phi (eq. 9's free case, SSMI's
``fuseObsFree``). A node is pruned when its 8 children hold identical occupancy and identical
semantics. The ``.ot`` file's node payload is the full state (layout in ``docs/mapping.md``), so
a saved map reloads into the same state (:func:`load_multiclass_bayes`).
"""

from __future__ import annotations

from os import PathLike

import numpy as np

from evsmap.data import Frame, SemanticObservation
from evsmap.mapping import fusion
from evsmap.mapping.fusion import MCBState
from evsmap.mapping.mcb_kernel import frame_update
from evsmap.mapping.occupancy import ScanUpdate
from evsmap.registry import UPDATERS
from evsmap.updaters.base import FramePoints, OctreeUpdater, strongest_child

PAYLOAD_FORMAT = np.dtype([("classes", "u1", (3,)), ("logodds", "i1", (3,)), ("others", "i1")])
"""Per-node payload after the float32 occupancy log-odds in the ``.ot`` stream (7 bytes): class
ids (255 = empty slot) and the class and "others" log-odds in units of ``quantum``."""
EMPTY_ID = 255
TREE_TYPE = "MultiClassBayesOcTree"

USE_KERNEL = True
"""Update the payloads with the compiled kernel (:mod:`evsmap.mapping.mcb_kernel`) when numba
is installed; False selects the numpy reference (the tests compare the two)."""


class MultiClassBayesMap(OctreeUpdater):
    """EVSMaP's multi-class Bayesian semantic octree.

    Args:
        psi: log-odds added to the observed class (eq. 9, phi+ of the occupied case).
        phi: log-odds added on a miss (eq. 9, phi-).
        theta: Algorithm 1's punishment value.
        quantum: step of the stored log-odds. The state lives on the lattice of the update
            constants ("log-odds piecewise constants", Section III-B): every value is rounded
            to a multiple of ``quantum`` (default ``|phi|`` = 0.1) after each update and stored
            as an ``int8`` count (the clamps +-9.21 are +-92 steps), so equal histories give
            exactly equal nodes, which prune, and a node's semantics take 7 bytes.
        (other arguments: :class:`~evsmap.updaters.base.OctreeUpdater`)
    """

    name = "multiclass-bayes"
    tree_type = TREE_TYPE
    uses_semantics = True

    def __init__(self, *, psi: float = fusion.PSI, phi: float = fusion.PHI,
                 theta: float = fusion.THETA, quantum: float | None = None, **kwargs) -> None:
        from evsmap.errors import InvalidDataError

        self.psi, self.phi, self.theta = float(psi), float(phi), float(theta)
        self.quantum = abs(self.phi) if quantum is None else float(quantum)
        if not self.quantum > 0 or fusion.MAX_LOGODDS / self.quantum > 127:
            raise InvalidDataError(
                f"quantum must be at least {fusion.MAX_LOGODDS / 127:.3f} (int8 steps up to the "
                f"+-{fusion.MAX_LOGODDS:.2f} clamp), got {quantum!r}")
        self._steps = int(np.floor(fusion.MAX_LOGODDS / self.quantum))
        super().__init__(**kwargs)

    def _init_payloads(self) -> None:
        self.map.add_payload("classes", np.int16, (3,), fill=fusion.EMPTY)
        self.map.add_payload("class_logodds", np.int8, (3,), fill=0)
        self.map.add_payload("others", np.int8, (), fill=0)

    def state(self, index: np.ndarray | slice = slice(None)) -> MCBState:
        m, q = self.map, self.quantum
        return MCBState(m.payload("classes")[index],
                        m.payload("class_logodds")[index].astype(np.float32) * q,
                        m.payload("others")[index].astype(np.float32) * q)

    def _quantize(self, values: np.ndarray) -> np.ndarray:
        steps = np.rint(np.asarray(values, dtype=np.float64) / self.quantum)
        return np.clip(steps, -self._steps, self._steps).astype(np.int8)

    def _store(self, index: np.ndarray, state: MCBState) -> None:
        m = self.map
        m.payload("classes")[index] = state.classes
        m.payload("class_logodds")[index] = self._quantize(state.logodds)
        m.payload("others")[index] = self._quantize(state.others)

    def _update_payloads(self, frame: Frame, points: FramePoints, update: ScanUpdate,
                         observation: SemanticObservation | None) -> None:
        self._check_classes(observation)
        if USE_KERNEL and frame_update is not None:
            pixels, voxels, local_index = self.endpoint_voxels(points)
            span = int(observation.classes.max()) + 1 if observation.classes.size else 0
            if 0 < span and len(voxels) * span <= fusion._DENSE_LIMIT:
                k = observation.k
                m = self.map
                frame_update(
                    m.payload("classes"), m.payload("class_logodds"), m.payload("others"),
                    update.free_index, voxels, local_index, pixels,
                    observation.classes.reshape(-1, k), observation.probs.reshape(-1, k),
                    span, self.quantum,
                    self._steps, self.psi, self.phi, self.theta, fusion.MIN_LOGODDS,
                    fusion.MAX_LOGODDS, fusion.PROB_MIN)
                return
        self._update_payloads_numpy(points, update, observation)

    def _update_payloads_numpy(self, points: FramePoints, update: ScanUpdate,
                               observation: SemanticObservation) -> None:
        """The reference implementation (numpy, whole arrays)."""
        # rays: lower the semantics of traversed voxels that have some
        free = update.free_index
        if free.size:
            has = self.map.payload("classes")[free, 0] >= 0
            idx = free[has]
            if idx.size:
                self._store(idx, fusion.mcb_miss(self.state(idx), phi=self.phi))
        # end points: local map of this frame, merged with Algorithm 1
        pixels, voxels, local_index = self.endpoint_voxels(points)
        if not voxels.size:
            return
        classes = observation.classes.reshape(-1, observation.k)[pixels]
        probs = observation.probs.reshape(-1, observation.k)[pixels]
        local = fusion.build_local(local_index, classes, probs, len(voxels), hit=self.psi)
        current = self.state(voxels)
        known = current.has_semantics
        merged = fusion.merge_algorithm1(current.take(known), local.take(known), self.theta)
        self._store(voxels[known], merged)
        self._store(voxels[~known], local.take(~known))

    def _payload_record(self) -> np.ndarray:
        rec = np.empty(self.map.num_leaves, dtype=PAYLOAD_FORMAT)
        classes = self.map.payload("classes")
        rec["classes"] = np.where(classes < 0, EMPTY_ID, classes)
        rec["logodds"] = self.map.payload("class_logodds")
        rec["others"] = self.map.payload("others")
        return rec

    def _set_payload_record(self, record: np.ndarray | None) -> None:
        ids = record["classes"].astype(np.int16)
        self.map.payload("classes")[:] = np.where(ids == EMPTY_ID, fusion.EMPTY, ids)
        self.map.payload("class_logodds")[:] = record["logodds"]
        self.map.payload("others")[:] = record["others"]

    def _equal_columns(self) -> list[np.ndarray]:
        m = self.map
        return [m.logodds, m.payload("classes"), m.payload("class_logodds"), m.payload("others")]

    def _inner_payload(self):
        return strongest_child("logodds")

    def _payload_format(self):
        return PAYLOAD_FORMAT

    def _node_bytes(self) -> int:
        # OctoMap node: 4 B log-odds + children pointer (8 B) + this payload, 8-byte aligned
        return -(-(4 + 8 + PAYLOAD_FORMAT.itemsize) // 8) * 8

    def _check_classes(self, observation: SemanticObservation) -> None:
        if observation.num_classes > EMPTY_ID:
            from evsmap.errors import InvalidDataError

            raise InvalidDataError(f"multiclass-bayes stores class ids in one byte: at most "
                                   f"{EMPTY_ID} classes, got {observation.num_classes}")

    def query(self, points: np.ndarray):
        return self._labelled_query(points, "classes")


def load_multiclass_bayes(path: str | PathLike[str], **kwargs) -> MultiClassBayesMap:
    """A :class:`MultiClassBayesMap` restored from its ``.ot`` file (mapping can continue);
    ``kwargs`` are the map's options (give the ``quantum`` it was built with, if not the
    default)."""
    from evsmap.mapping.octree_io import read_ot

    resolution = read_ot(path, payload_format={TREE_TYPE: PAYLOAD_FORMAT}).resolution
    return MultiClassBayesMap(resolution=resolution, **kwargs).restore(path)


@UPDATERS.register("multiclass-bayes",
                   description="EVSMaP: multi-class Bayesian semantic octree, local maps merged "
                               "with Algorithm 1 (theta 0.6)")
def multiclass_bayes(*, resolution: float = 0.05, max_range: float = 5.0,
                     discretize: bool = True, psi: float = fusion.PSI, phi: float = fusion.PHI,
                     theta: float = fusion.THETA, quantum: float | None = None,
                     prob_hit: float = 0.7, prob_miss: float = 0.4, clamp_min: float = 0.1192,
                     clamp_max: float = 0.971) -> MultiClassBayesMap:
    return MultiClassBayesMap(resolution=resolution, max_range=max_range, discretize=discretize,
                              psi=psi, phi=phi, theta=theta, quantum=quantum, prob_hit=prob_hit,
                              prob_miss=prob_miss, clamp_min=clamp_min, clamp_max=clamp_max)
