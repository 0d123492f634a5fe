"""evaluate_map: hand-built maps and small synthetic sequences."""

from __future__ import annotations

import math

import numpy as np
import pytest

from evsmap.errors import InvalidDataError
from evsmap.mapping.keys import KEY_OFFSET, pack
from evsmap.mapping.occupancy import OccupancyMap
from evsmap.metrics import evaluate_map, nearest_within, neighbour_offsets
from evsmap.registry import READERS, SEGMENTERS, UPDATERS
from evsmap.synth.groundtruth import VoxelLabels

RES = 0.1
OCC, FREE = 2.0, -2.0  # log-odds of an occupied / a free leaf


def _codes(keys) -> np.ndarray:
    return pack(np.asarray(keys, dtype=np.int64) + KEY_OFFSET)


def _updater(name: str, leaves: list[tuple[tuple[int, int, int], float, int]]):
    """An updater whose map holds exactly ``leaves``: (ground-truth-style key, log-odds,
    first class)."""
    up = UPDATERS.create(name, resolution=RES)
    codes = _codes([k for k, _, _ in leaves])
    up.map = OccupancyMap.from_leaves(RES, codes, [v for _, v, _ in leaves], params=up.params)
    up._init_payloads()
    if "classes" in up.map.payload_names:
        order = np.argsort(codes)
        up.map.payload("classes")[:, 0] = np.asarray([c for _, _, c in leaves])[order]
    return up


def _truth(keys, labels) -> VoxelLabels:
    return VoxelLabels(np.asarray(keys, np.int32), np.asarray(labels, np.uint8), RES)


def test_offsets_nearest_first():
    off = neighbour_offsets(1)
    assert len(off) == 27 and off[0].tolist() == [0, 0, 0]
    norms = (off ** 2).sum(axis=1)
    assert norms.tolist() == sorted(norms.tolist())
    assert len(neighbour_offsets(2)) == 125 and len(neighbour_offsets(0)) == 1


def test_nearest_within_prefers_the_voxel_itself():
    targets = np.sort(_codes([[0, 0, 0], [1, 0, 0], [5, 5, 5]]))
    got = nearest_within(np.asarray([[0, 0, 0], [1, 1, 1], [3, 3, 3], [6, 6, 6]]) + KEY_OFFSET,
                         targets, 1)
    idx = {int(c): i for i, c in enumerate(targets)}
    assert got.tolist() == [idx[int(_codes([[0, 0, 0]])[0])], idx[int(_codes([[1, 0, 0]])[0])],
                            -1, idx[int(_codes([[5, 5, 5]])[0])]]
    # keys at the edge of the key range do not wrap around
    assert nearest_within(np.array([[0, 0, 0]]), np.sort(pack(np.array([[0, 0, 65535]]))),
                          1).tolist() == [-1]


def test_hand_built_geometry_and_semantics():
    # ground truth: a row of 4 voxels, classes 1 1 2 3
    truth = _truth([[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]], [1, 1, 2, 3])
    up = _updater("multiclass-bayes", [
        ((0, 0, 0), OCC, 1),    # exact, right class
        ((1, 0, -1), OCC, 2),   # one below voxel 1 (slack): matched to (1,0,0) class 1 -> wrong
        ((2, 0, 0), OCC, 2),    # exact, right
        ((3, 0, 0), FREE, -1),  # known but free: observed, not covered... except by (2,0,0)
        ((9, 9, 9), OCC, 4),    # far from everything: a false positive
    ])
    q = evaluate_map(up, truth, num_classes=5)
    assert q.occupied == 4 and q.ground_truth == 4
    assert q.matched == 3 and q.precision == pytest.approx(3 / 4)
    # observed: voxels 0, 2, 3 have leaves (1 only has its neighbour below) -> 3
    assert q.observed == 3
    # covered (occupied leaf within 1 voxel): all four (3 is next to (2,0,0))
    assert q.recall == 1.0 and q.recall_total == 1.0
    # matched leaves: (1 vs 1) ok, (2 vs 1) wrong, (2 vs 2) ok
    assert q.semantic_accuracy == pytest.approx(2 / 3)
    assert q.semantics is not None and q.semantics.pixels == 3
    assert q.semantics.per_class_iou[1] == pytest.approx(1 / 2)
    assert q.semantics.per_class_iou[2] == pytest.approx(1 / 2)
    assert q.map_miou == pytest.approx(0.5)
    assert q.unlabelled == 0

    strict = evaluate_map(up, truth, slack_voxels=0, num_classes=5)
    assert strict.matched == 2 and strict.precision == pytest.approx(2 / 4)
    # covered without slack: voxels 0 and 2; observed 0, 2, 3
    assert strict.recall == pytest.approx(2 / 3) and strict.recall_total == pytest.approx(2 / 4)


def test_unlabelled_leaves_are_counted_apart():
    truth = _truth([[0, 0, 0], [4, 0, 0]], [1, 2])
    up = _updater("multiclass-bayes", [((0, 0, 0), OCC, -1), ((4, 0, 0), OCC, 2)])
    q = evaluate_map(up, truth, num_classes=3)
    assert q.matched == 2 and q.unlabelled == 1
    assert q.semantic_accuracy == 1.0 and q.semantics.pixels == 1


def test_geometry_only_updater_has_no_semantics():
    truth = _truth([[0, 0, 0], [1, 0, 0]], [1, 1])
    up = _updater("orgb", [((0, 0, 0), OCC, 0), ((1, 0, 0), OCC, 0)])
    q = evaluate_map(up, truth)
    assert q.precision == 1.0 and q.recall == 1.0
    assert q.semantic_accuracy is None and q.map_miou is None and q.semantics is None
    assert q.as_dict()["semantics"] is None


def test_empty_map_and_errors():
    truth = _truth([[0, 0, 0]], [1])
    up = UPDATERS.create("multiclass-bayes", resolution=RES)
    q = evaluate_map(up, truth)
    assert q.occupied == 0 and q.observed == 0 and math.isnan(q.precision)
    assert math.isnan(q.recall) and q.recall_total == 0.0
    assert q.as_dict()["precision"] is None
    with pytest.raises(InvalidDataError, match="resolution"):
        evaluate_map(up, VoxelLabels(truth.keys, truth.labels, 0.05))
    with pytest.raises(InvalidDataError, match="slack_voxels"):
        evaluate_map(up, truth, slack_voxels=-1)
    with pytest.raises(InvalidDataError, match="OctreeUpdater"):
        evaluate_map(object(), truth)


def test_occupied_labels_reads_the_first_class():
    up = _updater("multiclass-bayes", [((0, 0, 0), OCC, 5), ((1, 0, 0), FREE, 6),
                                       ((2, 0, 0), OCC, 7)])
    codes, labels = up.occupied_labels()
    assert codes.tolist() == sorted(_codes([[0, 0, 0], [2, 0, 0]]).tolist())
    assert labels.tolist() == [5, 7]


# -- a small synthetic sequence mapped with the oracle -----------------------------------------

@pytest.fixture(scope="module")
def sequence():
    seq = READERS.create("synthetic", frames=8, width=160, height=120)
    return list(seq), seq.ground_truth(RES)


def _map(frames, updater: str, **oracle):
    up = UPDATERS.create(updater, resolution=RES)
    seg = SEGMENTERS.create("oracle", **oracle) if up.uses_semantics else None
    for f in frames:
        up.integrate(f, None if seg is None else seg.predict(f))
    return up


PERFECT = dict(accuracy=1.0, boundary_accuracy=1.0)


@pytest.mark.parametrize("updater", ["multiclass-bayes", "orgb"])
def test_synthetic_geometry(sequence, updater):
    frames, truth = sequence
    q = evaluate_map(_map(frames, updater, **PERFECT), truth)
    assert q.precision > 0.9 and q.recall > 0.9
    assert 0 < q.recall_total <= q.recall  # 8 frames do not see every surface
    assert q.observed < q.ground_truth


def test_synthetic_semantics(sequence):
    frames, truth = sequence
    perfect = evaluate_map(_map(frames, "multiclass-bayes", **PERFECT), truth, num_classes=40)
    # remaining errors: voxels holding two classes, and wall/floor corners matched by the slack
    assert perfect.semantic_accuracy > 0.9
    # errors in 16 px patches do not average out inside a voxel
    noisy = evaluate_map(_map(frames, "multiclass-bayes", accuracy=0.6, error_block=16), truth,
                         num_classes=40)
    assert noisy.semantic_accuracy < perfect.semantic_accuracy - 0.1
    assert noisy.map_miou < perfect.map_miou
    assert noisy.precision == pytest.approx(perfect.precision)  # geometry does not change


def test_scene_miou_counts_what_the_map_dropped() -> None:
    """A map that kept half of class 0's voxels (both right) and all of class 1's, with one false
    leaf of class 1: IoU 2/4 and 2/3; the kept leaves alone would score 1.0."""
    import numpy as np

    from evsmap.metrics.mapping import scene_miou

    truth = np.array([0, 0, 0, 0, 1, 1])
    assert scene_miou(truth, np.array([0, 0, -1, -1, 1, 1]), np.array([1]), 2) == \
        pytest.approx((2 / 4 + 2 / 3) / 2)
    assert scene_miou(truth, truth, np.array([], dtype=int), 2) == 1.0
    assert scene_miou(truth, np.full(6, -1), np.array([-1]), 2) == 0.0  # nothing kept
    assert np.isnan(scene_miou(np.array([], dtype=int), np.array([], dtype=int),
                               np.array([], dtype=int), 3))
