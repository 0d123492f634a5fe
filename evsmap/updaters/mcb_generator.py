"""``multiclass-bayes`` on the ``octomap_generator`` front end: EVSMaP's update as SSMI's
generator runs it (ExistentialRobotics/SSMI, ``SSMI-Mapping``), the default of the MESAMap and
EVSMap rows of Table IV.

The paper builds its map on [13], whose code is SSMI, and defines Table IV's rows by one
difference: TESAMap and MESAMap use "the traditional voxel node update strategy from [14] and
our update strategy", "all other aspects remain consistent". SSMI's ``octomap_generator.cpp`` is
semantic_slam's with the node swapped, so this updater runs the same front end as
``classic-semantic`` (:mod:`evsmap.mapping.generator`) and SSMI's node rules
(:mod:`evsmap.mapping.ssmi_kernel`). Per frame (``OctomapGenerator::insertPointCloud``):

1. The semantic cloud: every valid depth pixel with its colour and its top class's colour packed
   in a float field (SSMI's ``semantic_sensor.py`` publishes one class colour per point), PCL's
   ``VoxelGrid`` at the map resolution in the camera frame - the packed colours are averaged as
   floats, so a leaf mixing classes carries a colour that is no class's, which SSMI then keeps as
   a class of its own -, the centroids moved to the world frame.
2. Every centroid within ``max_range``: ``updateNode(x, y, z, true, class_obs, color_obs,
   false)`` in the voxel grid's order (a world voxel holding two centroids is observed twice).
3. ``insertPointCloud(all centroids, origin, raycast_range, discretize=true)``, SSMI's override:
   only the free set is updated (``updateNode(key, false)``), the occupied set is left to step 2.

Where the paper changes SSMI, the paper wins: an inner node's semantics are its children's merged
with Algorithm 1 (theta 0.6, the paper's punishment) instead of SSMI's ``semanticFusion``
average, in child order over the children that have semantics (SSMI's
``getFusedChildSemantics``), its occupancy ``getOccFromSem`` of the result, its colour the
average of its children's. Pruning is SSMI's ``isNodeCollapsible``: 8 leaf children with equal
value and equal semantics, or equal value when the first child is free (``value <=
minOccupancyLogOdds``); the pruned node is child 0's copy with the children's average colour.

The map is kept as leaf arrays expanded to the finest level (evsmap's octree updaters). SSMI
prunes as it updates (``lazy_eval`` false) and expands a pruned node before updating one of its
voxels, and both change leaves: the pruned node is child 0's copy with the children's average
colour, and expanding it gives all 8 children that colour - and child 0's semantics, which for a
block of free leaves need not be theirs. ``pruned_leaves="copies"`` (the default, SSMI's) does
the same on the leaves (:mod:`evsmap.mapping.ssmi_prune`: after each update that passes
``checkNeedsUpdate``, the ancestors that collapse copy their data into their leaves, and the
``pruned_level`` column records which node holds each leaf); ``pruned_leaves="own"`` is
evsmap's earlier reading, a named variant: every leaf keeps its own colour and free semantics
whatever was pruned around it. The two differ only in the colours and the free semantics of
leaves that were inside a pruned block (TUM fr1_xyz at 2 cm: 97 leaves' colours).

Files: ``full`` keeps the whole node (value, colour, 3 x (class colour, log-odds), others) and
restores. ``published`` is the file SSMI saves: its ROS node calls ``setWriteSemantics(false)``
at the end of every cloud callback (``octomap_generator_ros.cpp`` line 131) and writes the tree
at shutdown, so ``writeData`` gives the value and the top semantic colour, 8 bytes a node, under
the id ``ColorOcTree`` that ``getTreeType`` reports - a ``ColorOcTree`` any OctoMap tool opens,
byte for byte the ``colour`` file. ``message`` is what the node sends on ``octomap_full``
(``fullMapToMsg`` while the nodes still write their semantics): value, the top semantic colour and
the raw ``SemanticsLogOdds`` struct (28 bytes with its padding), 36 bytes a node with the child
mask. SSMI sends it under the id ``ColorOcTree`` too, which no OctoMap reader can parse (it reads
8 bytes a node: octomap-python's ``ColorOcTree.read`` dies on such a file); as an ``.ot`` evsmap
writes it under :data:`MESSAGE_TREE_ID`, which OctoMap's tools refuse as unknown and evsmap reads.
In memory a node is 48 bytes (children pointer, float value, colour, the 28-byte semantics and
two flags, 8-byte aligned).

The node (columns, records, the message layout) is declared in :mod:`evsmap.mapping.mcb_nodes`;
SSMI's tree rules are :class:`GeneratorMultiClassBayesMap`'s methods: the frame
(:meth:`~GeneratorMultiClassBayesMap.update_frame`, on the shared
:class:`~evsmap.mapping.front_end.GeneratorFrontEnd`), inner and pruned nodes, the pruning
predicate, the inner occupancy and the files.
"""

from __future__ import annotations

from dataclasses import replace
from os import PathLike

import numpy as np

from evsmap.data import Frame, SemanticObservation
from evsmap.errors import InvalidDataError
from evsmap.mapping import fusion
from evsmap.mapping.front_end import GeneratorCloud, GeneratorFrontEnd
from evsmap.mapping.fusion import MCBState
from evsmap.mapping.generator import WHITE, as_float_parameter, pack_rgb, unpack_rgb, voc_colormap
from evsmap.mapping.kernels import Kernels
from evsmap.mapping.keys import TREE_DEPTH, morton, pack, unpack
from evsmap.mapping.mcb_nodes import (
    GENERATOR_NODE,
    LOGINIT,
    MESSAGE_TREE_ID,
    NODE_BYTES,
    PUBLISHED,
    RECORD,
    TREE_ID,
    colour_classes,
)
from evsmap.mapping.node_type import FileTree
from evsmap.mapping.options import OCTREE_DEFAULTS
from evsmap.mapping.raycast import octomap_keys, scan_keys
from evsmap.mapping.ssmi_kernel import frame_update, occupancies, tree_constants
from evsmap.mapping.tree import Tree, octomap_colour_average, octomap_colour_prune
from evsmap.updaters.base import OctreeUpdater
from evsmap.updaters.tree_map import FrontEndCounts

__all__ = ["LOGINIT", "MESSAGE_TREE_ID", "NODE_BYTES", "NODE_TYPE", "PRUNED_LEAVES", "PUBLISHED",
           "RECORD", "ROS_DEFAULTS", "TREE_ID", "GeneratorMultiClassBayesMap", "colour_classes"]

NODE_TYPE = GENERATOR_NODE

ROS_DEFAULTS = {"max_range": 5.0, "raycast_range": 2.0, "clamp_min": 1e-4, "clamp_max": 0.9999}
"""The generator's ranges as semantic_slam's ``octomap_generator.yaml`` sets them (TESAMap's, so
that the rows differ only by the node), and SSMI's clamping (its yaml: 0.0001 / 0.9999, which
SSMI's ``setClampingThresMin/Max`` also make the semantic log-odds' bounds). SSMI's own yaml sets
max_range 15 and raycast_range 10 for 0.5 m outdoor maps."""


PRUNED_LEAVES = ("copies", "own")
"""What the leaves of a block SSMI prunes hold (:class:`GeneratorMultiClassBayesMap`)."""


def _semantics_state(payload: np.ndarray) -> tuple[MCBState, np.ndarray]:
    """The records' semantics as an :class:`MCBState` whose class ids number the colours
    (Algorithm 1 compares classes by identity only), and the colour of each id."""
    colours = np.asarray(payload["colors"], dtype=np.uint32)
    palette, ids = np.unique(colours, return_inverse=True)
    ids = ids.reshape(colours.shape).astype(np.int64)
    ids[colours == WHITE] = fusion.EMPTY
    return MCBState(ids, np.asarray(payload["logodds"], np.float32),
                    np.asarray(payload["others"], np.float32)), palette


def _payload(tree: Tree) -> np.ndarray:
    """The tree's payload records (every tree of this node type has them)."""
    assert tree.payload is not None, "a tree of the generator's node type has a payload"
    return tree.payload


class _Hits:
    """One frame's hits on the generator front end: voxel codes (a code may repeat), their
    class colours and colours."""

    def __init__(self, cloud: GeneratorCloud, inside: np.ndarray, resolution: float) -> None:
        keys, ok = octomap_keys(cloud.centroids[inside], resolution)
        self.codes = pack(keys[ok])
        self.colour = np.ascontiguousarray(cloud.fields[inside][ok, 0]).view(np.uint32)
        self.rgb = np.ascontiguousarray(cloud.rgb[inside][ok])


class GeneratorMultiClassBayesMap(OctreeUpdater):
    """EVSMaP's multi-class Bayesian map on SSMI's ``octomap_generator`` (see the module notes).

    Args:
        psi, phi: SSMI's hit and miss log-odds steps (its yaml: 1 and -0.1).
        theta: Algorithm 1's punishment where nodes merge (the paper's 0.6).
        pairing: Algorithm 1's pairing (:class:`~evsmap.updaters.multiclass_bayes.
            MultiClassBayesMap`).
        raycast_range: free space is cast up to here (semantic_slam's 2 m).
        max_range: centroids within it are hits (5 m).
        clamp_min, clamp_max: SSMI's clamping probabilities, for the occupancy floor and the
            semantic log-odds (1e-4 / 0.9999).
        resolution: the leaf size; like every parameter it reaches the tree as a ``float``.
        kernels: the ray casting's (:class:`~evsmap.updaters.base.OctreeUpdater`); SSMI's node
            update is always the compiled :func:`~evsmap.mapping.ssmi_kernel.frame_update`.
        pruned_leaves: ``copies`` (SSMI's tree: a pruned block's leaves become copies of the
            pruned node, its colour the children's average) or ``own`` (each leaf keeps its
            own colour and free semantics; see the module notes).
    """

    semantics_within_range = True

    name = "multiclass-bayes"
    node_type = NODE_TYPE
    front_end = "generator"

    def __init__(self, *, psi: float = fusion.PSI, phi: float = fusion.PHI,
                 theta: float = fusion.THETA, pairing: str = "printed",
                 raycast_range: float = ROS_DEFAULTS["raycast_range"],
                 resolution: float = OCTREE_DEFAULTS.resolution,
                 max_range: float = ROS_DEFAULTS["max_range"],
                 clamp_min: float = ROS_DEFAULTS["clamp_min"],
                 clamp_max: float = ROS_DEFAULTS["clamp_max"],
                 occupancy_threshold: float = OCTREE_DEFAULTS.sensor.occupancy_threshold,
                 kernels: Kernels = OCTREE_DEFAULTS.kernels, pruned_leaves: str = "copies") -> None:
        if pruned_leaves not in PRUNED_LEAVES:
            raise InvalidDataError(f"multiclass-bayes: pruned_leaves must be one of "
                                   f"{', '.join(PRUNED_LEAVES)}; got {pruned_leaves!r}")
        self.pruned_leaves = pruned_leaves
        if pairing not in fusion.PAIRINGS:
            raise InvalidDataError(f"multiclass-bayes: pairing must be one of "
                                   f"{', '.join(fusion.PAIRINGS)}; got {pairing!r}")
        if not (isinstance(raycast_range, (int, float)) and np.isfinite(raycast_range)
                and raycast_range >= 0):
            raise InvalidDataError(f"multiclass-bayes: raycast_range must be a number of metres "
                                   f">= 0, got {raycast_range!r}")
        self.theta, self.pairing = float(theta), pairing
        self.raycast_range = as_float_parameter(raycast_range)
        self.num_classes = 0
        super().__init__(resolution=as_float_parameter(resolution),
                         max_range=as_float_parameter(max_range), discretize=True,
                         clamp_min=as_float_parameter(clamp_min),
                         clamp_max=as_float_parameter(clamp_max),
                         occupancy_threshold=as_float_parameter(occupancy_threshold),
                         kernels=kernels)
        self.psi, self.phi, self.min_logodds, self.max_logodds, self.min_occupancy = \
            tree_constants(psi=psi, phi=phi, clamp_min=clamp_min, clamp_max=clamp_max)

    # ---- one frame
    def update_frame(self, frame: Frame, observation: SemanticObservation | None
                     ) -> FrontEndCounts:
        """SSMI's ``insertPointCloud``: the semantic cloud's centroids within ``max_range``
        are hits, the free space is cast up to ``raycast_range``."""
        assert observation is not None  # uses_semantics: integrate checked it
        if int(observation.num_classes) > self.num_classes:  # the colour map grew: relabel
            self.num_classes = int(observation.num_classes)
            self.map.payload("classes")[:] = colour_classes(self.map.payload("sem_colors"),
                                                            self.num_classes)
        cloud = GeneratorFrontEnd(self.name, self.resolution).cloud(
            frame, lambda pixels: self._cloud_fields(frame, observation, pixels))
        valid = np.all(np.isfinite(cloud.centroids), axis=1)
        inside = valid & (cloud.distance().astype(np.float64) <= self.max_range)
        hits = _Hits(cloud, inside, self.resolution)
        keys = scan_keys(cloud.centroids[valid], cloud.origin.astype(np.float64),
                         self.resolution, max_range=self.raycast_range, discretize=True,
                         kernels=self.kernels)
        self.apply_updates(hits.codes, hits.colour, hits.rgb, keys.free)
        return FrontEndCounts(centroids=len(cloud.centroids), hits=len(hits.codes),
                              rays=int(np.count_nonzero(valid)))

    def _cloud_fields(self, frame: Frame, observation: SemanticObservation,
                      pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """SSMI's semantic cloud fields: the top class's colour packed in a float, the colour."""
        palette = pack_rgb(voc_colormap(max(self.num_classes, 1)))
        top = observation.classes.reshape(-1, observation.k)[pixels, 0].astype(np.int64)
        packed = np.where(top >= 0, palette[np.maximum(top, 0)], WHITE).astype(np.uint32)
        colours = frame.colors()
        rgb = (np.zeros((len(pixels), 3), np.uint8) if colours is None
               else np.ascontiguousarray(colours.reshape(-1, 3)[pixels], np.uint8))
        return packed.view(np.float32)[:, None], rgb

    def apply_updates(self, hit_codes: np.ndarray, hit_colour: np.ndarray, hit_rgb: np.ndarray,
                      free_codes: np.ndarray) -> None:
        """SSMI's node updates of one frame: ``updateNode(hit)`` for each voxel code of
        ``hit_codes`` in order (a code may repeat) with its class colour (``uint32``) and colour
        (``uint8`` r, g, b), then ``updateNode(free)`` for each of the sorted unique
        ``free_codes``; the leaves they need are inserted first."""
        codes = np.union1d(hit_codes, free_codes)
        m = self.map
        index, created = m.insert_leaves(codes)
        hit_index = index[np.searchsorted(codes, hit_codes)]
        free_index = index[np.searchsorted(codes, free_codes)]
        pending = np.zeros(m.num_leaves, dtype=bool)
        pending[index[created]] = True
        dirty = np.zeros(m.num_leaves, dtype=bool)
        frame_update(m.payload("sem_colors"), m.payload("class_logodds"), m.payload("others"),
                     m.logodds_for_writing(), m.payload("rgb"), hit_index,
                     np.ascontiguousarray(hit_colour, np.uint32),
                     np.ascontiguousarray(hit_rgb, np.uint8), free_index, self.psi, self.phi,
                     self.min_logodds, self.max_logodds, self.min_occupancy, m.codes,
                     m.payload("pruned_level"), pending, dirty, self.pruned_leaves == "copies")
        touched = np.flatnonzero(dirty)
        m.payload("classes")[touched] = colour_classes(m.payload("sem_colors")[touched],
                                                       self.num_classes)

    # ---- the tree's rules
    def inner_payload(self, children: np.ndarray, group: np.ndarray,
                      n_groups: int) -> np.ndarray:
        """An inner node: Algorithm 1 over the children that have semantics, in child order
        (SSMI skips the others; a parent with none keeps the unset semantics), the average child
        colour."""
        out = np.zeros(n_groups, dtype=RECORD)
        out["colors"] = WHITE
        out["logodds"] = LOGINIT
        out["others"] = LOGINIT
        has = (np.asarray(children["colors"]) != WHITE).any(axis=1)
        if has.any():
            state, palette = _semantics_state(children[has])
            g = group[has]
            owners = np.unique(g)
            local = np.searchsorted(owners, g)
            merged = fusion.fold_algorithm1(state, local, len(owners), self.theta,
                                            pairing=self.pairing)
            cls = merged.classes.astype(np.int64)
            out["colors"][owners] = np.where(cls >= 0, palette[np.maximum(cls, 0)], WHITE)
            out["logodds"][owners] = np.where(cls >= 0, merged.logodds, LOGINIT)
            out["others"][owners] = merged.others
        out["rgb"] = octomap_colour_average(children["rgb"], group, n_groups)
        return out

    def pruned_payload(self, children: np.ndarray, group: np.ndarray,
                       n_groups: int) -> np.ndarray:
        """SSMI's ``pruneNode``: child 0's copy, the colour averaged over the children."""
        first = np.flatnonzero(np.r_[True, group[1:] != group[:-1]])
        out = children[first].copy()
        out["rgb"] = octomap_colour_prune(children["rgb"], group, n_groups)
        return out

    def prune_columns(self) -> list[np.ndarray]:
        """SSMI's ``isNodeCollapsible``: equal value and semantics, or equal value with the
        first child free - the semantics of free leaves are left out of the comparison."""
        m = self.map
        free = m.logodds <= self.min_occupancy
        cols = np.where(free[:, None], 0, m.payload("sem_colors"))
        lo = np.where(free[:, None], 0, m.payload("class_logodds"))
        ot = np.where(free, 0, m.payload("others"))
        return [m.logodds, cols, lo, ot]

    def inner_occupancy(self, tree: Tree) -> Tree:
        """An inner node's value is ``getOccFromSem`` of its merged semantics (-0.1 for the
        unset semantics of a parent of free leaves only)."""
        if not tree.num_nodes:
            return tree
        inner = np.flatnonzero(tree.child_mask != 0)
        pay = _payload(tree)[inner]
        value = tree.value.copy()
        value[inner] = occupancies(np.ascontiguousarray(pay["colors"], np.uint32),
                                   np.ascontiguousarray(pay["logodds"], np.float32),
                                   np.ascontiguousarray(pay["others"], np.float32))
        return replace(tree, value=value)

    def load_tree(self, tree: Tree, path: str | PathLike[str]) -> None:
        """The leaves, then each leaf's ``pruned_level`` from the file's pruned nodes (a leaf of
        the file at depth d holds its voxels 16 - d levels up)."""
        super().load_tree(tree, path)
        if self.map.num_leaves:
            built = self.tree()
            leaf = built.child_mask == 0
            start = built.morton[leaf]
            voxel = morton(unpack(self.map.codes)).astype(np.int64)
            holder = np.searchsorted(start, voxel, side="right") - 1
            depth = built.depth[leaf][holder].astype(np.int64)
            self.map.payload("pruned_level")[:] = (TREE_DEPTH - depth).astype(np.uint8)

    # ---- files
    def message_file(self, tree: Tree) -> FileTree:
        """SSMI's ``writeData`` with the semantics (the ``octomap_full`` message's nodes),
        under :data:`MESSAGE_TREE_ID`."""
        rec = np.zeros(tree.num_nodes, dtype=PUBLISHED)
        pay = _payload(tree)
        rec["color"] = unpack_rgb(pay["colors"][:, 0])
        rec["slots"]["color"] = unpack_rgb(pay["colors"])
        rec["slots"]["logodds"] = pay["logodds"]
        rec["others"] = pay["others"]
        return FileTree(MESSAGE_TREE_ID, replace(tree, payload=rec), PUBLISHED)

    def colour_file(self, tree: Tree) -> FileTree:
        """``writeData`` with ``write_semantics`` off: value and the top semantic colour (the
        file SSMI saves, and its colour-only form)."""
        colours = unpack_rgb(_payload(tree)["colors"][:, 0])
        return FileTree("ColorOcTree", replace(tree, payload=colours), None)

    def published_file(self, tree: Tree) -> FileTree:
        """The file SSMI saves: :meth:`colour_file`."""
        return self.colour_file(tree)
