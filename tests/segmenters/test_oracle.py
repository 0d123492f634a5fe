"""The ``oracle`` segmenter: noisy top-k predictions from ground-truth labels (the mechanics,
mostly on the ``per-pixel`` profile, whose errors are independent: their rates show on one
frame)."""

from __future__ import annotations

import numpy as np
import pytest

from evsmap.data import VOID, Frame, Intrinsics, SemanticObservation
from evsmap.errors import EvsmapError, InvalidDataError
from evsmap.metrics.label_errors import window_extreme as _window_extreme
from evsmap.registry import SEGMENTERS
from evsmap.segmenters.oracle import OracleSegmenter

H, W = 240, 320


def blocks(h: int = H, w: int = W, size: int = 40) -> np.ndarray:
    """A label image of size x size squares with classes 0..39, a void square in the middle."""
    yy, xx = np.mgrid[0:h, 0:w]
    labels = ((yy // size) * 7 + (xx // size) * 3) % 40
    labels = labels.astype(np.uint8)
    labels[100:140, 140:180] = VOID
    return labels


def frame(labels: np.ndarray | None, *, name: str = "f0", timestamp: float = 1.0) -> Frame:
    h, w = (H, W) if labels is None else labels.shape
    return Frame(rgb=np.zeros((h, w, 3), np.uint8), depth=np.ones((h, w), np.float32),
                 intrinsics=Intrinsics(200.0, 200.0, w / 2, h / 2, w, h), pose=np.eye(4),
                 timestamp=timestamp, labels=labels, name=name)


def interior(labels: np.ndarray, r: int) -> np.ndarray:
    """Labelled pixels farther than r px (Chebyshev) from any label change."""
    hi = _window_extreme(labels, r, np.maximum)
    lo = _window_extreme(labels, r, np.minimum)
    return (hi == lo) & (labels != VOID)


def test_registered_with_keyword_options():
    seg = SEGMENTERS.create("oracle", accuracy=0.7, seed=3, k=2)
    assert isinstance(seg, OracleSegmenter)
    assert seg.module is None and seg.num_classes == 40 and len(seg.class_names) == 40
    assert seg.class_names[0] == "wall" and not seg.uses_depth
    params = SEGMENTERS.get("oracle").options
    assert {"num_classes", "accuracy", "confusion", "boundary_blur", "seed", "k"} <= set(params)
    with pytest.raises(EvsmapError, match="no option"):
        SEGMENTERS.create("oracle", bogus=1)


@pytest.mark.parametrize("accuracy", [0.85, 0.6, 1.0])
def test_measured_accuracy_away_from_boundaries(accuracy):
    labels = blocks()
    seg = OracleSegmenter(profile="per-pixel", accuracy=accuracy, boundary_blur=3, seed=1)
    obs = seg.predict(frame(labels))
    inside = interior(labels, 3)
    assert inside.sum() > 40000
    measured = (obs.argmax[inside] == labels[inside]).mean()
    assert abs(measured - accuracy) <= 0.02


def test_accuracy_holds_with_block_errors_and_adjacent_confusers():
    labels = blocks(480, 640, size=80)
    seg = OracleSegmenter(profile="per-pixel", accuracy=0.85, error_block=4,
                          confusion="adjacent", seed=2)
    obs = seg.predict(frame(labels))
    inside = interior(labels, 3)
    measured = (obs.argmax[inside] == labels[inside]).mean()
    assert abs(measured - 0.85) <= 0.02
    # block errors: a wrong pixel's right neighbour is wrong far more often than 15 %
    wrong = obs.argmax != labels
    pair = inside[:, :-1] & inside[:, 1:]
    assert (wrong[:, 1:][pair & wrong[:, :-1]]).mean() > 0.5


def test_wrong_labels_come_from_the_class_confusers():
    labels = blocks()
    seg = OracleSegmenter(profile="per-pixel", accuracy=0.5, seed=4)
    obs = seg.predict(frame(labels))
    inside = interior(labels, 3)
    wrong = inside & (obs.argmax != labels)
    allowed = seg.confusers[labels[wrong]]
    assert np.all(np.any(allowed == obs.argmax[wrong][:, None], axis=1))
    # the same table for every frame of this seed
    again = OracleSegmenter(profile="per-pixel", accuracy=0.5, seed=4)
    assert np.array_equal(again.confusers, seg.confusers)


def test_adjacent_confusers_are_touching_classes():
    labels = np.zeros((60, 80), np.uint8)
    labels[:, 40:] = 7
    labels[40:, :] = 3
    seg = OracleSegmenter(confusion="adjacent", seed=0)
    table, weights = seg._adjacent_confusers(labels)
    assert set(table[0][:2].tolist()) == {3, 7}
    assert table[0].size == 3 and weights[0].sum() == pytest.approx(1.0)


def test_deterministic_per_seed_and_frame():
    labels = blocks()
    a = OracleSegmenter(seed=5).predict(frame(labels))
    b = OracleSegmenter(seed=5).predict(frame(labels))
    assert np.array_equal(a.classes, b.classes) and np.array_equal(a.probs, b.probs)
    c = OracleSegmenter(seed=6).predict(frame(labels))
    assert not np.array_equal(a.classes, c.classes)
    # another frame (name or timestamp) of the same seed gets other noise
    d = OracleSegmenter(seed=5).predict(frame(labels, name="f1"))
    e = OracleSegmenter(seed=5).predict(frame(labels, timestamp=2.0))
    assert not np.array_equal(a.classes, d.classes)
    assert not np.array_equal(a.probs, e.probs)


@pytest.mark.parametrize("k", [1, 3, 5])
def test_probabilities_valid_and_sorted(k):
    labels = blocks()
    obs = OracleSegmenter(seed=7, k=3).predict(frame(labels), k=k)
    assert isinstance(obs, SemanticObservation)
    assert obs.classes.shape == (H, W, k) and obs.probs.dtype == np.float32
    assert obs.probs.min() > 0 and obs.probs.sum(axis=2).max() < 1.0
    assert np.all(np.diff(obs.probs, axis=2) <= 0)
    assert obs.classes.min() >= 0 and obs.classes.max() < 40
    # the k classes of a pixel are distinct
    srt = np.sort(obs.classes, axis=2)
    assert not np.any(srt[..., 1:] == srt[..., :-1])


def test_default_k_and_true_class_often_second_when_wrong():
    labels = blocks()
    obs = OracleSegmenter(profile="per-pixel", accuracy=0.6, seed=8).predict(frame(labels))
    assert obs.k == 3
    inside = interior(labels, 3)
    wrong = inside & (obs.argmax != labels)
    second = (obs.classes[..., 1] == labels)[wrong].mean()
    assert 0.65 <= second <= 0.75  # TRUE_SECOND = 0.7
    correct = inside & ~wrong
    assert obs.probs[..., 0][correct].mean() > obs.probs[..., 0][wrong].mean() + 0.15


def test_boundary_pixels_are_less_accurate_and_flatter():
    labels = blocks()
    seg = OracleSegmenter(profile="per-pixel", accuracy=0.9, boundary_blur=3,
                          boundary_accuracy=0.55, seed=9)
    obs = seg.predict(frame(labels))
    inside = interior(labels, 3)
    band = ~inside & (labels != VOID)
    right = obs.argmax == labels
    assert right[inside].mean() > 0.88
    assert abs(right[band].mean() - 0.55) <= 0.03
    assert obs.probs[..., 0][band].mean() < obs.probs[..., 0][inside].mean() - 0.1
    # a wrong boundary pixel takes the label from across the boundary
    wrong = band & ~right
    hi = _window_extreme(labels, 3, np.maximum)
    lo = _window_extreme(np.where(labels == VOID, 0, labels), 3, np.minimum)
    across = (obs.argmax == hi) | (obs.argmax == lo)
    assert across[wrong].mean() > 0.9
    # no blur: the band is as accurate as the interior
    flat = OracleSegmenter(profile="per-pixel", accuracy=0.9, boundary_blur=0,
                           seed=9).predict(frame(labels))
    assert abs((flat.argmax == labels)[band].mean() - 0.9) <= 0.03


def test_void_pixels_get_low_confidence():
    labels = blocks()
    obs = OracleSegmenter(profile="per-pixel", seed=10).predict(frame(labels))
    void = labels == VOID
    assert obs.probs[..., 0][void].mean() < 0.4
    assert obs.probs[..., 0][~void].mean() > 0.6
    assert len(np.unique(obs.argmax[void])) > 10  # not one fixed class


def test_missing_labels_name_the_frame():
    seg = OracleSegmenter()
    with pytest.raises(InvalidDataError, match="'kitchen_0007'"):
        seg.predict(frame(None, name="kitchen_0007"))


def test_labels_beyond_num_classes_are_rejected():
    labels = blocks()
    with pytest.raises(InvalidDataError, match="num_classes"):
        OracleSegmenter(num_classes=13).predict(frame(labels, name="x"))


@pytest.mark.parametrize("options", [{"accuracy": 1.5}, {"confusion": "magic"}, {"k": 0},
                                     {"error_block": 0}, {"num_classes": 1}])
def test_bad_options(options):
    with pytest.raises(InvalidDataError):
        OracleSegmenter(**options)


def test_call_uses_the_factory_k():
    labels = blocks()
    seg = SEGMENTERS.create("oracle", k=2)
    assert seg(frame(labels)).k == 2


def test_the_default_profiles_accuracy_holds_over_frames_that_see_different_places():
    """With errors correlated over patches and anchored to the scene, one frame's error rate
    varies; over frames seeing different places it is the profile's."""
    from evsmap.segmenters.oracle_profile import load_profile

    profile = load_profile("fitted").replace(class_accuracy={}, class_boundary_accuracy={})
    seg = OracleSegmenter(profile=profile, seed=11)
    labels = blocks()
    inside = interior(labels, profile.boundary_blur)
    rates = []
    for i in range(40):
        f = frame(labels, name=f"p{i}", timestamp=float(i))
        f.pose[:3, 3] = [7.0 * i, 3.0 * i, 0.0]  # a place of its own
        rates.append((seg.predict(f).argmax[inside] == labels[inside]).mean())
    assert abs(np.mean(rates) - profile.accuracy) < 0.04
    assert np.std(rates) > 0.02  # a network's per-frame accuracy varies too
