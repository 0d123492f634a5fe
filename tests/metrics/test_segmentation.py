"""ConfusionMatrix against hand-computed matrices and scores."""

from __future__ import annotations

import math

import numpy as np
import pytest

from evsmap.errors import InvalidDataError
from evsmap.metrics import ConfusionMatrix


def test_small_case_with_absent_class():
    # 4 classes; class 3 appears nowhere -> NaN, not in the mean
    gt = np.array([[0, 0, 1], [1, 2, 255]], dtype=np.uint8)
    pred = np.array([[0, 1, 1], [1, 2, 3]], dtype=np.int64)  # 3 only at the void pixel
    cm = ConfusionMatrix(4).update(pred, gt)
    expected = np.array([[1, 1, 0, 0],
                         [0, 2, 0, 0],
                         [0, 0, 1, 0],
                         [0, 0, 0, 0]])
    np.testing.assert_array_equal(cm.matrix, expected)
    assert cm.matrix.dtype == np.int64
    r = cm.result()
    # IoU: c0 = 1/(2+1-1) = 1/2, c1 = 2/(2+3-2) = 2/3, c2 = 1, c3 absent
    np.testing.assert_allclose(r.per_class_iou[:3], [0.5, 2 / 3, 1.0])
    assert math.isnan(r.per_class_iou[3])
    np.testing.assert_array_equal(r.present, [True, True, True, False])
    assert r.miou == pytest.approx((0.5 + 2 / 3 + 1.0) / 3)
    assert r.pixel_accuracy == pytest.approx(4 / 5)
    assert r.mean_accuracy == pytest.approx((0.5 + 1.0 + 1.0) / 3)
    # frequency weights 2/5, 2/5, 1/5
    assert r.frequency_weighted_iou == pytest.approx(0.4 * 0.5 + 0.4 * 2 / 3 + 0.2 * 1.0)
    assert r.pixels == 5


def test_class_only_in_predictions_has_iou_zero_and_counts():
    gt = np.array([0, 0, 0, 1], dtype=np.uint8)
    pred = np.array([0, 2, 0, 1])
    r = ConfusionMatrix(3).update(pred, gt).result()
    np.testing.assert_array_equal(ConfusionMatrix(3).update(pred, gt).matrix,
                                  [[2, 0, 1], [0, 1, 0], [0, 0, 0]])
    assert r.per_class_iou[2] == 0.0 and r.present[2]
    assert math.isnan(r.per_class_accuracy[2])  # not in the ground truth
    assert r.miou == pytest.approx((2 / 3 + 1.0 + 0.0) / 3)
    assert r.mean_accuracy == pytest.approx((2 / 3 + 1.0) / 2)
    assert r.pixel_accuracy == pytest.approx(3 / 4)


def test_all_void():
    gt = np.full((3, 3), 255, dtype=np.uint8)
    pred = np.full((3, 3), 7)  # out of range, but only at void pixels: ignored
    cm = ConfusionMatrix(2).update(pred, gt)
    assert cm.matrix.sum() == 0
    r = cm.result()
    assert r.pixels == 0
    assert all(math.isnan(x) for x in (r.miou, r.pixel_accuracy, r.mean_accuracy,
                                        r.frequency_weighted_iou))
    assert not r.present.any()
    d = r.as_dict()
    assert d["miou"] is None and d["per_class_iou"] == {}


def test_merge_equals_one_matrix_over_both_images():
    rng = np.random.default_rng(0)
    gts = [rng.integers(0, 5, (6, 7)).astype(np.uint8) for _ in range(3)]
    preds = [rng.integers(0, 5, (6, 7)) for _ in range(3)]
    gts[1][0, :] = 255
    whole = ConfusionMatrix(5)
    parts = []
    for p, g in zip(preds, gts, strict=True):
        whole.update(p, g)
        parts.append(ConfusionMatrix(5).update(p, g))
    merged = parts[0].merge(parts[1]).merge(parts[2])
    np.testing.assert_array_equal(merged.matrix, whole.matrix)
    # brute force
    brute = np.zeros((5, 5), dtype=np.int64)
    for p, g in zip(preds, gts, strict=True):
        for a, b in zip(g.ravel(), p.ravel(), strict=True):
            if a != 255:
                brute[a, b] += 1
    np.testing.assert_array_equal(whole.matrix, brute)
    assert whole.result().miou == pytest.approx(merged.result().miou)


def test_perfect_prediction():
    gt = np.array([[0, 1], [2, 255]], dtype=np.uint8)
    r = ConfusionMatrix(40).update(gt.astype(np.int64) % 255, gt).result()
    assert r.miou == 1.0 and r.pixel_accuracy == 1.0 and r.pixels == 3
    assert np.count_nonzero(r.present) == 3


def test_errors_are_clear():
    cm = ConfusionMatrix(3)
    with pytest.raises(InvalidDataError, match="prediction has class 3 .*outside \\[0, 2\\]"):
        cm.update(np.array([0, 3]), np.array([0, 1], dtype=np.uint8))
    with pytest.raises(InvalidDataError, match="prediction has class -1"):
        cm.update(np.array([-1]), np.array([1], dtype=np.uint8))
    with pytest.raises(InvalidDataError, match="ground truth has label 7"):
        cm.update(np.array([0]), np.array([7], dtype=np.uint8))
    with pytest.raises(InvalidDataError, match="shape"):
        cm.update(np.zeros((2, 2), int), np.zeros((2, 3), np.uint8))
    with pytest.raises(InvalidDataError, match="integer"):
        cm.update(np.zeros(2), np.zeros(2, np.uint8))
    with pytest.raises(InvalidDataError, match="cannot merge"):
        cm.merge(ConfusionMatrix(4))
    with pytest.raises(InvalidDataError, match="ignore_index"):
        ConfusionMatrix(3, ignore_index=1)
    assert cm.pixels == 0  # failed updates left no counts


def test_class_names_in_record():
    gt = np.array([0, 1], dtype=np.uint8)
    r = ConfusionMatrix(3).update(np.array([0, 1]), gt).result(class_names=("a", "b", "c"))
    assert r.as_dict()["per_class_iou"] == {"a": 1.0, "b": 1.0}
    with pytest.raises(InvalidDataError, match="2 class names for 3"):
        ConfusionMatrix(3).result(class_names=("a", "b"))


def test_from_matrix():
    m = np.array([[3, 1], [0, 2]])
    r = ConfusionMatrix.from_matrix(m).result()
    assert r.per_class_iou.tolist() == pytest.approx([3 / 4, 2 / 3])
    with pytest.raises(InvalidDataError):
        ConfusionMatrix.from_matrix(np.array([[1, -1], [0, 0]]))
