"""How a segmenter errs (evsmap/metrics/label_errors.py): the figures the oracle is fitted to."""

from __future__ import annotations

import numpy as np

from evsmap.data import VOID, Frame, Intrinsics, SemanticObservation
from evsmap.metrics.label_errors import LabelErrorStats, boundary_band, matched_pixels

H, W = 64, 128


def frame(labels: np.ndarray, *, pose: np.ndarray | None = None, name: str = "f") -> Frame:
    h, w = labels.shape
    return Frame(rgb=np.zeros((h, w, 3), np.uint8), depth=np.full((h, w), 2.0, np.float32),
                 intrinsics=Intrinsics(100.0, 100.0, w / 2, h / 2, w, h),
                 pose=np.eye(4) if pose is None else pose, timestamp=0.0, labels=labels,
                 name=name)


def observation(top1: np.ndarray, p1: float = 0.8, second: np.ndarray | None = None
                ) -> SemanticObservation:
    second = (top1 + 1) % 40 if second is None else second
    classes = np.stack([top1, second], axis=-1).astype(np.int16)
    probs = np.stack([np.full(top1.shape, p1), np.full(top1.shape, 0.1)], -1).astype(np.float32)
    return SemanticObservation(classes=classes, probs=probs, num_classes=40)


def halves() -> np.ndarray:
    labels = np.zeros((H, W), np.uint8)
    labels[:, W // 2:] = 7
    return labels


def test_band_is_the_pixels_near_a_label_change_with_the_label_across():
    band, across = boundary_band(halves(), 3)
    assert band[:, W // 2 - 3:W // 2 + 3].all() and not band[:, :W // 2 - 3].any()
    assert (across[:, W // 2 - 3:W // 2] == 7).all() and (across[:, W // 2:W // 2 + 3] == 0).all()


def test_interior_and_band_error_rates_per_class_and_the_bleeding_share():
    labels = halves()
    top1 = labels.astype(np.int64).copy()
    top1[:, W // 2:W // 2 + 2] = 0  # the left region bleeds 2 px into the right one
    top1[:10, :20] = 5  # an interior error patch of 200 px in class 0
    stats = LabelErrorStats(40, radius=3)
    stats.add(frame(labels), observation(top1))
    r = stats.result()
    interior = (labels.size - 6 * H)
    assert r["interior_error"] == 200 / interior
    assert r["band_error"] == 2 * H / (6 * H)
    assert r["band_errors_in_window"] == 1.0
    assert r["classes"][0]["taken_for"] == [[5, 200]]
    assert r["classes"][7]["band_error"] == 2 / 3 and r["classes"][0]["band_error"] == 0.0
    # two patches: 128 px (the bleed) and 200 px, area-weighted, at 640 px width (x 25)
    scale = (640 / W) ** 2
    expect = (128 ** 2 + 200 ** 2) / (128 + 200) * scale
    assert abs(r["patch_area"] - expect) < 1e-6


def test_confidence_when_right_and_wrong_and_the_true_second_class():
    labels = halves()
    top1 = labels.astype(np.int64).copy()
    top1[:10, :20] = 5
    second = np.where(top1 != labels, labels, 9)
    stats = LabelErrorStats(40, radius=0)
    stats.add(frame(labels), observation(top1, p1=0.6, second=second))
    r = stats.result()
    assert abs(r["top1_probability"]["wrong"]["mean"] - 0.6) < 1e-6
    assert r["top1_probability"]["correct"]["var"] < 1e-10
    assert r["true_second"] == 1.0


def test_autocorrelation_tells_patches_from_speckle():
    labels = np.zeros((H, W), np.uint8)
    rng = np.random.default_rng(0)
    speckle = np.where(rng.random((H, W)) < 0.2, 3, 0)
    blocks = np.kron(rng.random((H // 8, W // 8)) < 0.2, np.ones((8, 8))).astype(int) * 3
    result = {}
    for name, top1 in (("speckle", speckle), ("blocks", blocks)):
        stats = LabelErrorStats(40, radius=0)
        stats.add(frame(labels), observation(top1))
        result[name] = stats.result()["autocorrelation"]
    assert abs(result["speckle"]["1"]) < 0.1  # lag 1 at 640 px = 1 px here (rounded up)
    assert result["blocks"]["1"] > 0.6


def test_persistence_pairs_the_same_surface_point_in_consecutive_frames():
    labels = np.ones((H, W), np.uint8)
    shift = np.eye(4)
    shift[0, 3] = 8 * 2.0 / 100.0  # 8 px at 2 m, f = 100
    a, b = frame(labels, name="a"), frame(labels, pose=shift, name="b")
    i0, i1 = matched_pixels(a, b)
    assert len(i0) > 0 and np.all(i0 % W == i1 % W + 8)
    rng = np.random.default_rng(1)
    wrong_a = rng.random((H, W)) < 0.3
    wrong_b = np.zeros_like(wrong_a)
    wrong_b[:, :-8] = wrong_a[:, 8:]  # the same points wrong in the second frame
    for same, expect in ((wrong_b, 1.0), (rng.random((H, W)) < 0.3, 0.0)):
        stats = LabelErrorStats(40, radius=0)
        stats.add(a, observation(np.where(wrong_a, 2, 1)), same_world=True)
        stats.add(b, observation(np.where(same, 2, 1)), same_world=True)
        assert abs(stats.result()["persistence"] - expect) < 0.05
    stats = LabelErrorStats(40, radius=0)
    stats.add(a, observation(np.where(wrong_a, 2, 1)))
    stats.add(b, observation(np.where(wrong_b, 2, 1)))  # not paired: no persistence
    assert stats.result()["persistence"] is None


def test_void_pixels_count_for_nothing_but_the_void_confidence():
    labels = halves()
    labels[:, :10] = VOID
    stats = LabelErrorStats(40, radius=0)
    stats.add(frame(labels), observation(np.full((H, W), 3)))
    r = stats.result()
    assert r["pixels"]["interior"] == H * (W - 10)
    assert r["top1_probability"]["void"]["pixels"] == 10 * H
