"""The ``oracle`` segmenter: ground-truth labels turned into a noisy top-k prediction.

It stands in for a trained network when a sequence has labels (the synthetic scenes, NYUv2), so
the mapping experiments can run with a segmenter of known, controllable quality.

Noise model (all draws from one generator seeded by ``(seed, frame name, frame timestamp)``, so a
frame always gets the same prediction and different seeds give different ones):

* Top-1. A labelled pixel's top-1 is its true class with probability ``accuracy``, else a wrong
  class. Pixels within ``boundary_blur`` px (Chebyshev distance) of a label boundary use
  ``min(boundary_accuracy, accuracy)`` instead, and their wrong class is the label across the
  boundary (the largest, else the smallest, other label inside the window) - the way a network
  bleeds a neighbouring region into an edge. Elsewhere (and where no labelled neighbour exists)
  the wrong class is drawn from the true class's confusers.
* Confusers. Each class has 3 other classes with fixed weights. ``confusion="seeded"``: drawn once
  from ``seed`` (a fixed random confusion matrix, the same for every frame: a chair is always
  mistaken for the same few classes). ``confusion="adjacent"``: per frame, the classes touching the
  class in the label image (4-neighbour contacts), weighted by contact length, completed from the
  seeded set when a class touches fewer than 3.
* Spatial coherence. The accuracy and confuser draws are shared by square blocks of
  ``error_block`` px (1 = every pixel independent) on a grid with a random offset per frame, so
  errors come in patches as a network's do and do not simply average out inside a voxel.
* Slots 2..k. A correct pixel continues with a confuser of its class (drawn by weight), then the
  other confusers. A wrong pixel puts its true class second with probability 0.7, else the true
  class is left out. Classes ``top1 + 1, top1 + 2, ...`` (mod num_classes) fill any remaining slot,
  so the k classes are always distinct.
* Probabilities. The top-1 probability is Beta distributed (concentration 12) with mean 0.80 for a
  correct interior pixel, 0.55 for a wrong one, 0.60 / 0.50 in the boundary band (flatter). Of the
  rest, a fraction drawn from U(0.75, 0.98) is spread over slots 2..k with geometrically decaying
  jittered weights; the remainder is the mass of the classes not kept. Probabilities are
  non-increasing along k and sum to less than 1.
* Void pixels (label 255) have no true class: their top-k are random classes with a flat,
  low-confidence distribution (top-1 mean 0.30), so fusion gives them little weight. (Mapping
  them to a catch-all class such as NYUv2's 'otherprop' would invent confident labels.)
"""

from __future__ import annotations

import struct
import zlib
from typing import ClassVar

import numpy as np

from evsmap.classes import class_names_for
from evsmap.data import VOID, Frame, SemanticObservation
from evsmap.errors import InvalidDataError
from evsmap.interfaces import Segmenter
from evsmap.registry import SEGMENTERS

CONFUSERS = 3
"""Confuser classes per class."""

TRUE_SECOND = 0.7
"""Probability that a wrong pixel's true class is its second class."""

CONCENTRATION = 12.0
"""Beta concentration (a + b) of the top-1 probability."""

MEAN_TOP1 = {"correct": 0.80, "wrong": 0.55, "edge_correct": 0.60, "edge_wrong": 0.50,
             "void": 0.30}
"""Mean top-1 probability per kind of pixel."""

CONFUSION_MODES = ("seeded", "adjacent")


def _window_extreme(a: np.ndarray, r: int, fn) -> np.ndarray:
    """Separable (2r+1)^2 max/min filter with edge padding."""
    out = a
    for axis in (0, 1):
        pad = [(0, 0), (0, 0)]
        pad[axis] = (r, r)
        p = np.pad(out, pad, mode="edge")
        n = out.shape[axis]
        acc = np.take(p, np.arange(0, n), axis=axis)
        for s in range(1, 2 * r + 1):
            acc = fn(acc, np.take(p, np.arange(s, s + n), axis=axis))
        out = acc
    return out


def _frame_seed(seed: int, frame: Frame) -> np.random.SeedSequence:
    name = zlib.crc32(frame.name.encode("utf-8"))
    stamp = zlib.crc32(struct.pack("<d", frame.timestamp))
    return np.random.SeedSequence([seed, name, stamp])


class OracleSegmenter(Segmenter):
    """Noisy top-k predictions from a frame's ground-truth labels (see the module notes)."""

    uses_depth: ClassVar[bool] = False

    def __init__(self, *, num_classes: int = 40, accuracy: float = 0.85,
                 confusion: str = "seeded", boundary_blur: int = 3,
                 boundary_accuracy: float = 0.55, error_block: int = 1, seed: int = 0,
                 k: int = 3) -> None:
        if isinstance(num_classes, bool) or not isinstance(num_classes, (int, np.integer)) \
                or not 2 <= num_classes <= 255:
            raise InvalidDataError(f"oracle: num_classes must be in [2, 255], got {num_classes!r}")
        for name, value in (("accuracy", accuracy), ("boundary_accuracy", boundary_accuracy)):
            if not 0.0 <= float(value) <= 1.0:
                raise InvalidDataError(f"oracle: {name} must lie in [0, 1], got {value!r}")
        if confusion not in CONFUSION_MODES:
            raise InvalidDataError(f"oracle: confusion must be one of {CONFUSION_MODES}, "
                                   f"got {confusion!r}")
        if int(boundary_blur) < 0:
            raise InvalidDataError(f"oracle: boundary_blur must be >= 0, got {boundary_blur!r}")
        if int(error_block) < 1:
            raise InvalidDataError(f"oracle: error_block must be >= 1, got {error_block!r}")
        if not 1 <= int(k) <= num_classes:
            raise InvalidDataError(f"oracle: k must lie in [1, {num_classes}], got {k!r}")
        self.name = "oracle"
        self.num_classes = int(num_classes)
        self.class_names = class_names_for(self.num_classes)
        self.accuracy = float(accuracy)
        self.boundary_accuracy = min(float(boundary_accuracy), self.accuracy)
        self.confusion = confusion
        self.boundary_blur = int(boundary_blur)
        self.error_block = int(error_block)
        self.seed = int(seed)
        self.k = int(k)
        self.confusers, self.confuser_weights = self._seeded_confusers()

    @property
    def module(self) -> None:
        return None

    # -- confusers ----------------------------------------------------------------------------
    def _seeded_confusers(self) -> tuple[np.ndarray, np.ndarray]:
        """(C, m) confuser classes and their weights (sorted, summing to 1), fixed by seed."""
        c = self.num_classes
        m = min(CONFUSERS, c - 1)
        rng = np.random.default_rng(np.random.SeedSequence([self.seed, 0x0C0F]))
        # Random keys with the class itself excluded; the m smallest are its confusers.
        keys = rng.random((c, c))
        keys[np.arange(c), np.arange(c)] = np.inf
        table = np.argsort(keys, axis=1)[:, :m]
        weights = -np.sort(-rng.dirichlet(np.ones(m), size=c), axis=1)
        return table, weights

    def _adjacent_confusers(self, labels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per-frame confusers: classes touching each class, by contact length."""
        c = self.num_classes
        table, weights = self.confusers.copy(), self.confuser_weights.copy()
        m = table.shape[1]
        pairs = [(labels[:, :-1], labels[:, 1:]), (labels[:-1, :], labels[1:, :])]
        counts = np.zeros(c * c, dtype=np.int64)
        for a, b in pairs:
            a = a.ravel().astype(np.int64)
            b = b.ravel().astype(np.int64)
            keep = (a != b) & (a != VOID) & (b != VOID)
            a, b = a[keep], b[keep]
            counts += np.bincount(a * c + b, minlength=c * c)
            counts += np.bincount(b * c + a, minlength=c * c)
        contact = counts.reshape(c, c).astype(np.float64)
        order = np.argsort(-contact, axis=1, kind="stable")[:, :m]
        top = np.take_along_axis(contact, order, axis=1)
        for cls in np.flatnonzero(top[:, 0] > 0):  # loop over classes, not pixels
            touching = order[cls][top[cls] > 0]
            fill = [x for x in self.confusers[cls] if x not in touching][: m - touching.size]
            table[cls] = np.concatenate([touching, np.asarray(fill, dtype=np.int64)])
            w = top[cls][top[cls] > 0]
            # Touching classes share 90 % by contact length, fill-ins the rest equally.
            if fill:
                w = np.concatenate([0.9 * w / w.sum(), np.full(len(fill), 0.1 / len(fill))])
            weights[cls] = w / w.sum()
        return table, weights

    # -- prediction ---------------------------------------------------------------------------
    def _block_uniform(self, rng: np.random.Generator, shape: tuple[int, int],
                       n: int) -> np.ndarray:
        """(n, H, W) uniforms shared by ``error_block`` px squares (offset grid)."""
        h, w = shape
        b = self.error_block
        if b == 1:
            return rng.random((n, h, w))
        oy, ox = rng.integers(0, b, size=2)
        gy = (np.arange(h) + oy) // b
        gx = (np.arange(w) + ox) // b
        grid = rng.random((n, int(gy[-1]) + 1, int(gx[-1]) + 1))
        return grid[:, gy[:, None], gx[None, :]]

    def predict(self, frame: Frame, *, k: int | None = None) -> SemanticObservation:
        k = self.k if k is None else int(k)
        if not 1 <= k <= self.num_classes:
            raise InvalidDataError(f"oracle: k must lie in [1, {self.num_classes}], got {k}")
        frame.require_images("the oracle segmenter")
        if frame.labels is None:
            raise InvalidDataError(
                f"oracle segmenter needs ground-truth labels, but frame {frame.name!r} "
                f"(t={frame.timestamp}) has none")
        labels = frame.labels
        void = labels == VOID
        if np.any(~void & (labels >= self.num_classes)):
            bad = int(labels[~void].max())
            raise InvalidDataError(
                f"oracle: frame {frame.name!r} has label {bad}, but num_classes is "
                f"{self.num_classes}")
        c = self.num_classes
        rng = np.random.default_rng(_frame_seed(self.seed, frame))
        if self.confusion == "adjacent":
            table, weights = self._adjacent_confusers(labels)
        else:
            table, weights = self.confusers, self.confuser_weights
        m = table.shape[1]
        true = np.where(void, 0, labels).astype(np.intp)

        # Boundary band and the label across the boundary.
        r = self.boundary_blur
        if r > 0:
            band = _window_extreme(labels, r, np.maximum) != _window_extreme(labels, r, np.minimum)
            lab = labels.astype(np.int16)
            hi = _window_extreme(np.where(void, -1, lab), r, np.maximum)
            lo = _window_extreme(np.where(void, 999, lab), r, np.minimum)
            across = np.where((hi != true) & (hi >= 0), hi,
                              np.where((lo != true) & (lo < 999), lo, -1))
        else:
            band = np.zeros(labels.shape, dtype=bool)
            across = np.full(labels.shape, -1, dtype=np.int16)
        band &= ~void

        # Top-1: correct or a wrong class. Confuser j of the true class is picked when the
        # uniform falls in [cum_{j-1}, cum_j) of its weights.
        u_err, u_pick, u_second = self._block_uniform(rng, labels.shape, 3)
        acc = np.where(band, self.boundary_accuracy, self.accuracy)
        correct = (u_err < acc) & ~void
        cum = np.cumsum(weights, axis=1)[true]  # (H, W, m)
        options = table.astype(np.int32)[true]  # (H, W, m)
        pick = np.minimum((u_pick[..., None] >= cum).sum(axis=2), m - 1)
        confuser = np.take_along_axis(options, pick[..., None], axis=2)[..., 0]
        wrong = np.where(band & (across >= 0), across, confuser)
        random_cls = rng.integers(0, c, size=(3,) + labels.shape, dtype=np.int32)
        top1 = np.where(void, random_cls[0], np.where(correct, true, wrong)).astype(np.int32)

        # Slots 2..k: candidate list, duplicates removed, first k kept.
        pick2 = np.minimum((u_second[..., None] >= cum).sum(axis=2), m - 1)
        second = np.take_along_axis(options, pick2[..., None], axis=2)[..., 0]
        true_second = rng.random(labels.shape) < TRUE_SECOND
        ranked = [top1,
                  np.where(void, random_cls[1], np.where(true_second, true, top1)),
                  np.where(void, random_cls[2], second)]
        ranked += [np.where(void, top1, options[..., j]) for j in range(m)]
        ranked += [(top1 + j) % c for j in range(1, k)]
        cand = np.stack(ranked, axis=2).astype(np.int32)
        fresh = np.ones(cand.shape, dtype=bool)
        for i in range(1, cand.shape[2]):
            fresh[..., i] = ~np.any(cand[..., i:i + 1] == cand[..., :i], axis=2)
        rank = np.cumsum(fresh, axis=2) - 1
        # k distinct classes always exist: top1 and top1 + 1 .. top1 + k - 1 (mod C).
        classes = np.stack(
            [np.take_along_axis(cand, np.argmax(fresh & (rank == j), axis=2)[..., None],
                                axis=2)[..., 0] for j in range(k)], axis=2)

        # Probabilities.
        mean = np.select(
            [void, band & correct, band, correct],
            [MEAN_TOP1["void"], MEAN_TOP1["edge_correct"], MEAN_TOP1["edge_wrong"],
             MEAN_TOP1["correct"]], default=MEAN_TOP1["wrong"])
        p1 = rng.beta(mean * CONCENTRATION, (1.0 - mean) * CONCENTRATION)
        p1 = np.clip(p1, 0.05, 0.995)
        probs = np.empty(classes.shape, dtype=np.float64)
        probs[..., 0] = p1
        if k > 1:
            keep = rng.uniform(0.75, 0.98, size=labels.shape)
            w = 0.55 ** np.arange(1, k) * rng.uniform(0.7, 1.3, size=labels.shape + (k - 1,))
            w = -np.sort(-w, axis=2)
            w /= w.sum(axis=2, keepdims=True)
            probs[..., 1:] = ((1.0 - p1) * keep)[..., None] * w
        probs = np.minimum.accumulate(probs.astype(np.float32), axis=2)
        return SemanticObservation(classes=classes.astype(np.int16), probs=probs,
                                   num_classes=c)


@SEGMENTERS.register(
    "oracle",
    description="Ground-truth labels with controlled noise (accuracy, confusers, boundaries)",
)
def oracle(
    *,
    num_classes: int = 40,
    accuracy: float = 0.85,
    confusion: str = "seeded",
    boundary_blur: int = 3,
    boundary_accuracy: float = 0.55,
    error_block: int = 1,
    seed: int = 0,
    k: int = 3,
) -> OracleSegmenter:
    """Noisy top-k predictions from a frame's ground-truth labels (needs labelled frames)."""
    return OracleSegmenter(num_classes=num_classes, accuracy=accuracy, confusion=confusion,
                           boundary_blur=boundary_blur, boundary_accuracy=boundary_accuracy,
                           error_block=error_block, seed=seed, k=k)
