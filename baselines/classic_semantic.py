"""``classic-semantic`` and ``classic-semantic-max``: the "traditional voxel node update
strategy" of EVSMaP's reference [14], as semantic_slam implements it (TESAMap / TFEAGMap rows of
Table IV).

Each leaf holds OctoMap occupancy, the averaged RGB colour of its points and semantics:

* Bayesian variant: the top-3 (class, confidence) fused with semantic_slam's Bayesian rule
  (:func:`baselines.semantic_slam_fusion.fuse_bayes`: ALPHA 0.8, EPSILON 0.001).
* Max variant: one (class, confidence) fused with its max rule
  (:func:`baselines.semantic_slam_fusion.fuse_max`).

semantic_slam first filters a frame with a voxel grid at the map resolution, so each voxel gets
one observation per frame; here that observation is the mean of the top-k distributions of the
frame's points in the voxel (its top 3, or its top 1 for the max variant). A voxel without
semantics copies the observation. Pruning needs exactly equal occupancy and semantics (colour
ignored); an inner node carries the semantics of its most confident child.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from baselines import classic_semantic_kernels, semantic_slam_fusion
from baselines.semantic_slam_node import voc_colormap
from evsmap.mapping import fusion
from evsmap.mapping.front_end import DirectScan
from evsmap.mapping.node_type import NODE_TYPES, Column, FileTree, NodeType
from evsmap.mapping.tree import Tree
from evsmap.updaters.base import (
    OctreeUpdater,
    strongest_child,
)


def voxel_distributions(voxel: np.ndarray, classes: np.ndarray, probs: np.ndarray,
                        n_voxels: int, slots: int) -> tuple[np.ndarray, np.ndarray]:
    """Top-``slots`` classes (-1 where fewer) and mean probabilities of the points' top-k
    distributions per voxel (a class missing from a point's top-k counts as 0 for it)."""
    state = fusion.build_local(voxel, classes, probs, n_voxels, hit=0.0,
                               max_logodds=np.inf, min_logodds=-np.inf)
    conf = np.where(state.valid, np.exp(state.logodds.astype(np.float64)), 0.0)
    return state.classes[:, :slots], conf[:, :slots].astype(np.float32)


_NO_COLOURS = np.zeros((0, 3), np.uint8)


def _update(updater: ClassicSemanticMap, scan: DirectScan) -> None:
    """The frame's colours and semantics on its hit voxels: ``averageNodeColor`` and one
    fusion per voxel of the mean distribution of its points: the compiled kernel
    (:mod:`baselines.classic_semantic_kernels`), or the numpy reference (:func:`fuse_frame`)
    with ``kernels="reference"``."""
    observation = scan.observation
    assert observation is not None  # uses_semantics: integrate checked it
    pixels, voxels, local = updater.endpoint_voxels(scan.points)
    if not voxels.size:
        return
    m = updater.map
    colors = scan.frame.colors()
    k = observation.k
    args = (m.payload("sem_classes"), m.payload("sem_conf"), m.payload("rgb"), voxels, local,
            pixels, observation.classes.reshape(-1, k), observation.probs.reshape(-1, k))
    if updater.kernels == "compiled" and classic_semantic_kernels.frame_update(
            *args, _NO_COLOURS if colors is None else colors, colors is not None,
            updater.slots == 3, fusion.PROB_MIN, fusion.DENSE_LIMIT):
        return
    fuse_frame(*args, colors)


def fuse_frame(sem_classes: np.ndarray, sem_conf: np.ndarray, rgb: np.ndarray,
               voxels: np.ndarray, local: np.ndarray, pixels: np.ndarray, obs_classes: np.ndarray,
               obs_probs: np.ndarray, colors: np.ndarray | None) -> None:
    """The reference frame update (numpy, whole arrays), in place.

    Args:
        sem_classes, sem_conf, rgb: the leaf payloads (``int16`` (N, S), ``float32`` (N, S),
            ``uint8`` (N, 3); S = 3: Bayesian fusion, 1: max).
        voxels: map rows of the distinct hit voxels; ``local``: each point's position among
            them; ``pixels``: each point's flat pixel index.
        obs_classes, obs_probs: the observation's (H*W, k) top-k classes and probabilities.
        colors: the frame's (H*W, 3) colours, or None.
    """
    fusion.average_frame_colours(rgb, colors, pixels, voxels, local)
    slots = sem_classes.shape[1]
    obs_c, obs_p = voxel_distributions(local, obs_classes[pixels], obs_probs[pixels],
                                       len(voxels), slots)
    old_c = sem_classes[voxels]
    old_p = sem_conf[voxels]
    if slots == 3:
        new_c, new_p = semantic_slam_fusion.fuse_bayes(old_c, old_p, obs_c, obs_p)
    else:
        c, p = semantic_slam_fusion.fuse_max(old_c[:, 0], old_p[:, 0], obs_c[:, 0], obs_p[:, 0])
        new_c, new_p = np.asarray(c)[:, None], np.asarray(p)[:, None]
    sem_classes[voxels] = new_c
    sem_conf[voxels] = new_p


_strongest = strongest_child("conf")


def _publish(tree: Tree) -> FileTree:
    """semantic_slam's own file: its node type reports ``ColorOcTree`` and ``writeData``
    writes the float log-odds and the top class's colour (semantic_slam's VOC colour map;
    ``getSemanticColor``: white, 255/255/255, for a node without semantics), 8 bytes a node
    with the child mask; any OctoMap tool opens it. Inner nodes show the top class of their
    semantics here (the strongest child's; semantic_slam fuses the children)."""
    assert tree.payload is not None  # a tree of this node type has its payload
    top = np.asarray(tree.payload["classes"])[:, 0].astype(np.int64)
    colours = np.full((len(top), 3), 255, dtype=np.uint8)
    known = top >= 0
    if known.any():
        colours[known] = voc_colormap(int(top.max()) + 1)[top[known]]
    return FileTree("ColorOcTree", replace(tree, payload=colours), None)


def _node_type(rule: str) -> NodeType:
    slots = 3 if rule == "bayes" else 1
    record = np.dtype([("rgb", "u1", (3,)), ("classes", "<i2", (slots,)),
                       ("conf", "<f4", (slots,))])

    def encode(columns, n: int) -> np.ndarray:
        rec = np.empty(n, dtype=record.newbyteorder("="))
        rec["rgb"] = columns["rgb"]
        rec["classes"] = columns["sem_classes"]
        rec["conf"] = columns["sem_conf"]
        return rec

    def decode(rec: np.ndarray) -> dict[str, np.ndarray]:
        return {"rgb": rec["rgb"], "sem_classes": rec["classes"], "sem_conf": rec["conf"]}

    return NODE_TYPES.add(NodeType(
        "SemanticOcTreeBayes" if rule == "bayes" else "SemanticOcTreeMax", record=record,
        columns=(Column("rgb", np.uint8, (3,), fill=255),
                 Column("sem_classes", np.int16, (slots,), fill=fusion.EMPTY),
                 Column("sem_conf", np.float32, (slots,), fill=0.0)),
        prune_on=("sem_classes", "sem_conf"),
        # semantic_slam: a max node is 32 B and a Bayesian node 48 B in RAM
        node_bytes=48 if rule == "bayes" else 32,
        label="sem_classes", colour="rgb", encode=encode, decode=decode, uses_semantics=True,
        description=f"[14] direct-front-end variant, {rule} fusion: RGB + {slots} x (class, conf)"))


NODE_TYPES_BY_RULE = {"bayes": _node_type("bayes"), "max": _node_type("max")}
"""The direct front end's node types: colour, semantics (top 3 or top 1), strongest child for
inner nodes, pruning on equal occupancy and semantics (colour ignored)."""


class ClassicSemanticMap(OctreeUpdater):
    """semantic_slam's semantic octree (Bayesian or max fusion) on the direct front end
    (evsmap's cleaner variant).

    Args:
        fusion_rule: ``"bayes"`` (top-3) or ``"max"`` (top-1).
        (other arguments: :class:`~evsmap.updaters.base.OctreeUpdater`)
    """

    semantics_within_range = True

    def __init__(self, *, fusion_rule: str = "bayes", **kwargs) -> None:
        if fusion_rule not in ("bayes", "max"):
            from evsmap.errors import UnknownNameError

            raise UnknownNameError(f"unknown fusion rule {fusion_rule!r} (known: bayes, max)")
        self.fusion_rule = fusion_rule
        self.slots = 3 if fusion_rule == "bayes" else 1
        super().__init__(node_type=NODE_TYPES_BY_RULE[fusion_rule],
                         name="classic-semantic" if fusion_rule == "bayes"
                         else "classic-semantic-max", **kwargs)

    # -- the tree's rules: semantic_slam's update, the strongest child, its published file
    def update_payload(self, scan: DirectScan) -> None:
        _update(self, scan)

    def inner_payload(self, children: np.ndarray, group: np.ndarray,
                      n_groups: int) -> np.ndarray:
        return _strongest(children, group, n_groups)

    def published_file(self, tree: Tree) -> FileTree:
        return _publish(tree)
