"""3D quality of a finished octree map against voxel ground truth (the synthetic scenes', a ScanNet
scene's labelled mesh).

Voxels are compared by integer key at the map's resolution. The ground truth
(:class:`evsmap.data.VoxelLabels`) keys a voxel as ``floor(coordinate / resolution)``,
the map as OctoMap does, ``floor(coordinate / resolution) + 2**15``; the offset is added to the
ground truth before comparing. Surfaces lying exactly on voxel boundaries (the synthetic walls at
x = 0, y = 0 and the floor at z = 0) may land on either side, so a match allows ``slack_voxels``
of Chebyshev distance:

* precision: occupied map leaves with a ground-truth voxel within the slack;
* recall (observed): ground-truth voxels the map knows (a free or occupied leaf exists at the
  voxel itself) with an occupied leaf within the slack; total recall divides by every
  ground-truth voxel instead;
* semantics (updaters with ``uses_semantics``): every occupied leaf that has a ground-truth voxel
  within the slack is matched to the nearest one (the voxel itself, then face, edge and corner
  neighbours, then further rings; ties in a fixed offset order) and its most likely class is
  compared with that voxel's class in a :class:`~evsmap.metrics.segmentation.ConfusionMatrix`
  (semantic accuracy = its pixel accuracy, map mIoU = its mIoU). Matched leaves without a class
  are counted apart (``unlabelled``) and left out of the matrix.
* scene mIoU (:func:`scene_miou`): the map's mIoU over the *observed scene*, where the map
  mIoU above scores only the leaves the map kept: every observed ground-truth voxel takes the
  class of the nearest occupied leaf within the slack, a voxel with none (or with a leaf without
  a class) is a miss of its class, and an occupied leaf with no ground-truth voxel within the
  slack is a false positive of its class. A map that drops most of the scene and keeps its sure
  leaves has a high map mIoU and a low scene mIoU.
* a ground-truth voxel labelled void (:data:`~evsmap.data.VOID`: surface without a class, e.g.
  ScanNet's unannotated mesh) counts for geometry (precision, recall) and for matching, never
  for the semantic scores: a leaf matched to it is left out of the matrix (as a void pixel in
  2D), and it is not a voxel of the scene mIoU.

Everything is vectorised over voxels: a neighbourhood lookup is one ``np.searchsorted`` of the
packed codes per offset.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from evsmap.data import VOID
from evsmap.errors import InvalidDataError
from evsmap.interfaces import MapUpdater
from evsmap.mapping.keys import KEY_MAX, KEY_OFFSET, pack, unpack
from evsmap.metrics.segmentation import ConfusionMatrix, SegmentationResult

if TYPE_CHECKING:
    from typing_extensions import TypeIs


@dataclass(frozen=True)
class MapQuality:
    """Geometric and semantic quality of one map (fractions; NaN where undefined).

    Attributes:
        resolution: leaf size, metres.
        slack_voxels: Chebyshev tolerance of a match, in voxels.
        occupied: occupied map leaves.
        ground_truth: ground-truth occupied voxels.
        observed: ground-truth voxels known (free or occupied) in the map.
        precision: occupied leaves within the slack of a ground-truth voxel / occupied.
        recall: observed ground-truth voxels within the slack of an occupied leaf / observed.
        recall_total: ground-truth voxels within the slack of an occupied leaf / ground_truth.
        matched: occupied leaves matched to a ground-truth voxel (precision's numerator).
        unlabelled: matched leaves without a class (semantic updaters; 0 otherwise).
        semantic_accuracy: matched labelled leaves whose class is the ground truth's / all of
            them (``None`` for updaters without semantics).
        map_miou: mIoU of the same matrix (``None`` without semantics).
        semantic_accuracy_all: matched leaves whose class is the ground truth's / all matched
            leaves, a leaf without a class counting as wrong (``None`` without semantics).
        scene_miou: mIoU over the observed scene (:func:`scene_miou`; ``None`` without
            semantics).
        semantics: the full :class:`SegmentationResult` of the matched leaves, or ``None``.
    """

    resolution: float
    slack_voxels: int
    occupied: int
    ground_truth: int
    observed: int
    precision: float
    recall: float
    recall_total: float
    matched: int
    unlabelled: int = 0
    semantic_accuracy: float | None = None
    map_miou: float | None = None
    semantic_accuracy_all: float | None = None
    scene_miou: float | None = None
    semantics: SegmentationResult | None = field(default=None, repr=False)

    def as_dict(self) -> dict:
        out = {k: getattr(self, k) for k in (
            "resolution", "slack_voxels", "occupied", "ground_truth", "observed", "precision",
            "recall", "recall_total", "matched", "unlabelled", "semantic_accuracy", "map_miou",
            "semantic_accuracy_all", "scene_miou")}
        for k, v in out.items():
            if isinstance(v, float) and np.isnan(v):
                out[k] = None
        out["semantics"] = None if self.semantics is None else self.semantics.as_dict()
        return out


def neighbour_offsets(slack: int) -> np.ndarray:
    """``int64`` (M, 3) offsets with Chebyshev norm <= ``slack``, nearest first: sorted by
    Chebyshev norm, then squared Euclidean length, then lexicographically (so (0, 0, 0) first)."""
    r = np.arange(-slack, slack + 1)
    off = np.stack(np.meshgrid(r, r, r, indexing="ij"), axis=-1).reshape(-1, 3)
    order = np.lexsort((off[:, 2], off[:, 1], off[:, 0], (off ** 2).sum(axis=1),
                        np.abs(off).max(axis=1)))
    return off[order].astype(np.int64)


def nearest_within(query_keys: np.ndarray, target_codes: np.ndarray, slack: int) -> np.ndarray:
    """For each of the (N, 3) map keys, the index in the sorted ``target_codes`` of the nearest
    target voxel within Chebyshev distance ``slack`` (see :func:`neighbour_offsets`), else -1."""
    query_keys = np.asarray(query_keys, dtype=np.int64).reshape(-1, 3)
    target_codes = np.asarray(target_codes, dtype=np.int64)
    found = np.full(len(query_keys), -1, dtype=np.int64)
    if not len(query_keys) or not target_codes.size:
        return found
    for off in neighbour_offsets(slack):
        todo = np.flatnonzero(found < 0)
        if not todo.size:
            break
        keys = query_keys[todo] + off
        inside = np.all((keys >= 0) & (keys <= KEY_MAX), axis=1)
        todo, keys = todo[inside], keys[inside]
        codes = pack(keys)
        pos = np.searchsorted(target_codes, codes)
        pos_ok = np.minimum(pos, target_codes.size - 1)
        hit = (pos < target_codes.size) & (target_codes[pos_ok] == codes)
        found[todo[hit]] = pos[hit]
    return found


class _LeafArrays(Protocol):
    def index(self, codes: np.ndarray) -> tuple[np.ndarray, np.ndarray]: ...


class _LeafMapUpdater(Protocol):
    """What :func:`evaluate_map` reads of an updater beyond :class:`MapUpdater`: the leaf arrays
    (``map``) that an updater with ``has_leaf_map`` set holds (evsmap's ``OctreeUpdater``)."""

    @property
    def map(self) -> _LeafArrays: ...


def _has_leaf_map(updater: object) -> TypeIs[_LeafMapUpdater]:
    """Whether ``updater`` is a :class:`MapUpdater` that declares a leaf map."""
    return isinstance(updater, MapUpdater) and updater.has_leaf_map


def _ratio(num: int | np.integer, den: int) -> float:
    return float(num) / den if den else float("nan")


def evaluate_map(updater, ground_truth, *, slack_voxels: int = 1,
                 num_classes: int | None = None) -> MapQuality:
    """Score the occupied leaves of ``updater`` (an
    :class:`~evsmap.updaters.base.OctreeUpdater`) against ``ground_truth``
    (:class:`~evsmap.data.VoxelLabels` at the map's resolution).

    Args:
        slack_voxels: Chebyshev tolerance of a match, in voxels (1: the 27-neighbourhood).
        num_classes: size of the label set of the semantic scores (default: one more than the
            largest class id in the ground truth or the map).

    Raises:
        InvalidDataError: resolutions differ, a negative slack, or an updater that exposes no
            leaf map.
    """
    if isinstance(slack_voxels, bool) or not isinstance(slack_voxels, (int, np.integer)) \
            or slack_voxels < 0:
        raise InvalidDataError(f"slack_voxels must be an integer >= 0, got {slack_voxels!r}")
    if not (isinstance(updater, MapUpdater) and _has_leaf_map(updater)):
        raise InvalidDataError(
            f"{type(updater).__name__} exposes no leaf map (evaluate_map needs an OctreeUpdater)")
    resolution = float(updater.resolution)
    # a map built as the ROS nodes run keeps the resolution as a float (0.05f): equal to float
    if np.float32(resolution) != np.float32(ground_truth.resolution):
        raise InvalidDataError(f"the map's resolution is {resolution} m but the ground truth's "
                               f"is {ground_truth.resolution} m")
    slack = int(slack_voxels)

    gt_keys = np.asarray(ground_truth.keys, dtype=np.int64).reshape(-1, 3) + KEY_OFFSET
    gt_labels = np.asarray(ground_truth.labels, dtype=np.int64).ravel()
    inside = np.all((gt_keys >= 0) & (gt_keys <= KEY_MAX), axis=1)
    gt_keys, gt_labels = gt_keys[inside], gt_labels[inside]
    gt_codes = pack(gt_keys)
    order = np.argsort(gt_codes, kind="stable")
    gt_codes, gt_keys, gt_labels = gt_codes[order], gt_keys[order], gt_labels[order]

    occ_codes, occ_labels = updater.occupied_labels()
    occ_codes = np.asarray(occ_codes, dtype=np.int64)
    occ_labels = np.asarray(occ_labels, dtype=np.int64)
    occ_keys = unpack(occ_codes)

    # precision: each occupied leaf's nearest ground-truth voxel within the slack
    match = nearest_within(occ_keys, gt_codes, slack)
    matched = match >= 0
    # recall: ground-truth voxels with an occupied leaf within the slack
    covered = nearest_within(gt_keys, np.sort(occ_codes), slack) >= 0
    _, known = updater.map.index(gt_codes)
    n_gt, n_occ = int(gt_codes.size), int(occ_codes.size)
    n_observed = int(np.count_nonzero(known))

    quality: dict[str, Any] = dict(
        resolution=resolution, slack_voxels=slack, occupied=n_occ, ground_truth=n_gt,
        observed=n_observed, precision=_ratio(np.count_nonzero(matched), n_occ),
        recall=_ratio(np.count_nonzero(covered & known), n_observed),
        recall_total=_ratio(np.count_nonzero(covered), n_gt),
        matched=int(np.count_nonzero(matched)))
    if not updater.uses_semantics:
        return MapQuality(**quality)

    pred = occ_labels[matched]
    truth = gt_labels[match[matched]]
    labelled = pred >= 0
    classed = gt_labels != VOID  # a surface voxel without a class scores geometry only
    if num_classes is None:
        top = max(int(truth[truth != VOID].max()) if np.any(truth != VOID) else -1,
                  int(pred.max()) if pred.size else -1,
                  int(gt_labels[classed].max()) if classed.any() else -1)
        num_classes = max(top + 1, 1)
    cm = ConfusionMatrix(num_classes)  # ignores VOID ground truth
    cm.update(pred[labelled], truth[labelled])
    result = cm.result()
    # the scene: each observed ground-truth voxel's nearest occupied leaf (sorted codes)
    order = np.argsort(occ_codes, kind="stable")
    scored = known & classed
    near = nearest_within(gt_keys[scored], occ_codes[order], slack)
    scene_pred = np.where(near >= 0, occ_labels[order][np.maximum(near, 0)], -1)
    scene = scene_miou(gt_labels[scored], scene_pred, occ_labels[~matched], num_classes)
    return MapQuality(**quality, unlabelled=int(np.count_nonzero(~labelled)),
                      semantic_accuracy=result.pixel_accuracy, map_miou=result.miou,
                      semantic_accuracy_all=_ratio(np.count_nonzero(pred == truth), len(pred)),
                      scene_miou=scene, semantics=result)


def scene_miou(truth: np.ndarray, predicted: np.ndarray, false_leaves: np.ndarray,
               num_classes: int) -> float:
    """The mIoU over the observed scene: ``truth`` the classes of the observed ground-truth
    voxels, ``predicted`` the class the map gives each (-1: none, a miss), ``false_leaves`` the
    classes of the occupied leaves that match no ground-truth voxel (false positives; -1: a leaf
    without a class, not counted). Per class c: TP = voxels of c predicted c, and IoU = TP /
    (voxels of c + predictions of c - TP), predictions counting the voxels' and the false
    leaves'; the mean over the classes present in either (NaN when none is)."""
    truth = np.asarray(truth, dtype=np.int64)
    predicted = np.asarray(predicted, dtype=np.int64)
    false_leaves = np.asarray(false_leaves, dtype=np.int64)
    k = int(num_classes)
    hit = truth[(predicted == truth) & (truth >= 0)]
    tp = np.bincount(hit[hit < k], minlength=k)[:k]
    actual = np.bincount(truth[(truth >= 0) & (truth < k)], minlength=k)[:k]
    said = np.concatenate([predicted, false_leaves])
    claimed = np.bincount(said[(said >= 0) & (said < k)], minlength=k)[:k]
    union = actual + claimed - tp
    present = union > 0
    return float(np.mean(tp[present] / union[present])) if present.any() else float("nan")
