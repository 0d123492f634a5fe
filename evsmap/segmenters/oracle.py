"""The ``oracle`` segmenter: ground-truth labels turned into a noisy top-k prediction.

It stands in for a trained network when a sequence has labels (the synthetic scenes, NYUv2), so
the mapping experiments can run with a segmenter of known, controllable quality. Its settings
come from a profile (:mod:`evsmap.segmenters.oracle_profile`): ``fitted`` (the default, fitted
to a trained network's errors: docs/oracle.md), ``per-pixel`` (the model before 2026-11-29) or
``noise-free``, or a user's file; options given override the profile's value of the same name.

Noise model (all draws from generators seeded by ``(seed, frame name, frame timestamp)``, so a
frame always gets the same prediction and different seeds give different ones):

* Top-1. A labelled pixel's top-1 is its true class with probability ``accuracy`` (per class:
  ``class_accuracy``), else a wrong class. Pixels within ``boundary_blur`` px (Chebyshev
  distance) of a label boundary use ``min(boundary_accuracy, accuracy)`` (per class:
  ``class_boundary_accuracy``) instead, and with probability ``boundary_across`` their wrong
  class is the label across the boundary (the largest, else the smallest, other label inside the
  window) - the way a network bleeds a neighbouring region into an edge. Elsewhere (and where no
  labelled neighbour exists) the wrong class is drawn from the true class's confusers.
* Confusers. Each class has 3 other classes with weights. ``confusion="seeded"``: drawn once
  from ``seed`` (a fixed random confusion matrix, the same for every frame: a chair is always
  mistaken for the same few classes). ``confusion="adjacent"``: per frame, the classes touching the
  class in the label image (4-neighbour contacts), weighted by contact length, completed from the
  seeded set when a class touches fewer than 3. ``confusion="fitted"``: the profile's
  ``confusers`` (a network's most frequent mistakes per class), completed from the seeded set.
* Spatial coherence. The accuracy and confuser draws read uniforms that are correlated in the
  image and in the scene (:mod:`evsmap.segmenters.oracle_field`): with ``error_scale`` > 0 a
  Gaussian field of that correlation length (px at 640 px width), a share ``world_share`` of it
  anchored to the scene's 3D points so errors persist from frame to frame; with ``error_scale``
  0, squares of ``error_block`` px on a grid with a random offset per frame (1 = every pixel
  independent: the ``per-pixel`` profile).
* Slots 2..k. A correct pixel continues with a confuser of its class (drawn by weight), then the
  other confusers. A wrong pixel puts its true class second with probability ``true_second``,
  else the true class is left out. Classes ``top1 + 1, top1 + 2, ...`` (mod num_classes) fill any
  remaining slot, so the k classes are always distinct.
* Probabilities. The top-1 probability is Beta distributed (concentration ``concentration``)
  with mean ``mean_top1`` of its kind (correct / wrong, interior / boundary band, void). Of the
  rest, a fraction drawn from U(0.75, 0.98) is spread over slots 2..k with geometrically decaying
  jittered weights; the remainder is the mass of the classes not kept. Probabilities are
  non-increasing along k and sum to less than 1.
* Void pixels (label 255) have no true class: their top-k are random classes with a flat,
  low-confidence distribution, so fusion gives them little weight. (Mapping them to a catch-all
  class such as NYUv2's 'otherprop' would invent confident labels.)
"""

from __future__ import annotations

import struct
import zlib
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from evsmap.classes import class_names_for
from evsmap.data import VOID, Frame, SemanticObservation
from evsmap.errors import InvalidDataError
from evsmap.interfaces import Segmenter
from evsmap.metrics.label_errors import REFERENCE_WIDTH, boundary_band
from evsmap.registry import SEGMENTERS, Takes
from evsmap.segmenters.oracle_field import FieldMemo, uniform_fields
from evsmap.segmenters.oracle_profile import (
    DEFAULT_PROFILE,
    OracleProfile,
    load_profile,
)

CONFUSERS = 3
"""Confuser classes per class."""

OVERRIDABLE = ("accuracy", "boundary_accuracy", "boundary_blur", "confusion", "error_block",
               "error_scale", "world_share")
"""The profile settings the segmenter also takes as options (``-s accuracy=0.9``)."""

_FIELD_SALT = 0xF1E1D


def _frame_seed(seed: int, frame: Frame, *salt: int) -> np.random.SeedSequence:
    name = zlib.crc32(frame.name.encode("utf-8"))
    stamp = zlib.crc32(struct.pack("<d", frame.timestamp))
    return np.random.SeedSequence([seed, name, stamp, *salt])


def resolve_profile(profile: str | Path | OracleProfile = DEFAULT_PROFILE,
                    **overrides: Any) -> OracleProfile:
    """The profile with the options given (not None) in place of its values; ``accuracy`` or
    ``boundary_accuracy`` given replaces the per-class values too (it holds for every class)."""
    base = profile if isinstance(profile, OracleProfile) else load_profile(profile)
    given = {k: v for k, v in overrides.items() if v is not None}
    unknown = set(given) - set(OVERRIDABLE)
    if unknown:
        raise InvalidDataError(f"oracle: unknown option(s) {', '.join(sorted(unknown))}")
    if not given:
        return base
    for key in ("boundary_blur", "error_block"):
        if key in given:
            given[key] = int(given[key])
    for key in ("accuracy", "boundary_accuracy", "error_scale", "world_share"):
        if key in given:
            given[key] = float(given[key])
    named = ", ".join(f"{k}={v}" for k, v in sorted(given.items()))
    # an accuracy given holds for every class: it replaces the profile's per-class values
    if "accuracy" in given:
        given["class_accuracy"] = {}
    if "boundary_accuracy" in given:
        given["class_boundary_accuracy"] = {}
    return base.replace(**given, name=f"{base.name} ({named})")


class OracleSegmenter(Segmenter):
    """Noisy top-k predictions from a frame's ground-truth labels (see the module notes)."""

    uses_depth: ClassVar[bool] = False
    """Depth is not a network input; a profile with ``world_share`` > 0 reads it to anchor
    its errors to the scene."""

    def __init__(self, *, profile: str | Path | OracleProfile = DEFAULT_PROFILE,
                 num_classes: int = 40, seed: int = 0, k: int = 3,
                 memo: FieldMemo | None = None, **overrides: Any) -> None:
        if isinstance(num_classes, bool) or not isinstance(num_classes, (int, np.integer)) \
                or not 2 <= num_classes <= 255:
            raise InvalidDataError(f"oracle: num_classes must be in [2, 255], got {num_classes!r}")
        if not 1 <= int(k) <= num_classes:
            raise InvalidDataError(f"oracle: k must lie in [1, {num_classes}], got {k!r}")
        self.profile = resolve_profile(profile, **overrides)
        p = self.profile
        self.name = "oracle"
        self.num_classes = int(num_classes)
        self.class_names = class_names_for(self.num_classes)
        self.accuracy = float(p.accuracy)
        self.boundary_accuracy = min(float(p.boundary_accuracy), self.accuracy)
        self.confusion = p.confusion
        self.boundary_blur = int(p.boundary_blur)
        self.error_block = int(p.error_block)
        self.seed = int(seed)
        self.k = int(k)
        self.memo = memo
        """Fields kept across calls (the fit draws the same frames under many settings)."""
        self.confusers, self.confuser_weights = self._seeded_confusers()
        if p.confusion == "fitted":
            self.confusers, self.confuser_weights = self._fitted_confusers()
        self.class_accuracy, self.class_boundary_accuracy = self._class_accuracies()

    @property
    def module(self) -> None:
        return None

    def identity(self) -> dict[str, Any]:
        """What decides this oracle's predictions, for cache keys: its profile's settings
        digest, the seed, k and the class count (and the code's version: the model's module
        digest)."""
        from evsmap.cache import source_digest

        return {"segmenter": "oracle", "profile": self.profile.name,
                "settings": self.profile.digest(), "seed": self.seed, "k": self.k,
                "num_classes": self.num_classes, "code": source_digest("evsmap.segmenters")}

    # -- per-class tables ---------------------------------------------------------------------
    def _class_accuracies(self) -> tuple[np.ndarray, np.ndarray]:
        """(C,) interior and boundary accuracies: the profile's per-class values, else its
        global ones; the boundary's never above the interior's."""
        c = self.num_classes
        inner = np.full(c, self.accuracy)
        edge = np.full(c, self.boundary_accuracy)
        for cls, value in self.profile.class_accuracy.items():
            if 0 <= cls < c:
                inner[cls] = value
        for cls, value in self.profile.class_boundary_accuracy.items():
            if 0 <= cls < c:
                edge[cls] = value
        return inner, np.minimum(edge, inner)

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

    def _fitted_confusers(self) -> tuple[np.ndarray, np.ndarray]:
        """The profile's confusers, each class completed from its seeded ones (the fitted
        ones keep 90 % of the weight when completed)."""
        table, weights = self.confusers.copy(), self.confuser_weights.copy()
        m = table.shape[1]
        for cls, pairs in self.profile.confusers.items():
            if not 0 <= cls < self.num_classes:
                continue
            kept = [(o, w) for o, w in pairs if 0 <= o < self.num_classes and o != cls
                    and w > 0][:m]
            if not kept:
                continue
            chosen = [o for o, _ in kept]
            fill = [x for x in self.confusers[cls] if x not in chosen][: m - len(chosen)]
            w = np.asarray([w for _, w in kept], dtype=np.float64)
            w = w / w.sum()
            if fill:
                w = np.concatenate([0.9 * w, np.full(len(fill), 0.1 / len(fill))])
            table[cls] = chosen + fill
            weights[cls] = w
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

    def _uniforms(self, rng: np.random.Generator, frame: Frame,
                  shape: tuple[int, int], n: int = 3) -> np.ndarray:
        """The correlated uniforms of the error draws (module notes): "is it wrong", "which
        confuser", "which second class"; the first ``n`` of them (the squares always draw
        three, so the main generator's later draws do not depend on ``n``)."""
        p = self.profile
        if p.error_scale <= 0 and p.world_share <= 0:
            return self._block_uniform(rng, shape, 3)[:n]
        field_rng = np.random.default_rng(_frame_seed(self.seed, frame, _FIELD_SALT))
        sigma = p.error_scale * shape[1] / REFERENCE_WIDTH
        return uniform_fields(field_rng, frame, n, sigma=sigma, world_share=p.world_share,
                              world_scale=p.world_scale, key=self.seed, memo=self.memo)

    def _correct(self, u_err: np.ndarray, labels: np.ndarray, band: np.ndarray) -> np.ndarray:
        """Which labelled pixels keep their true class as top-1."""
        void = labels == VOID
        true = np.where(void, 0, labels).astype(np.intp)
        acc = np.where(band, self.class_boundary_accuracy[true], self.class_accuracy[true])
        return (u_err < acc) & ~void

    def error_mask(self, frame: Frame, band: np.ndarray | None = None) -> np.ndarray:
        """The labelled pixels whose top-1 :meth:`predict` gets wrong, without the rest of the
        prediction (the same draws: what the fit of the error field simulates); ``band``: the
        frame's boundary band at ``boundary_blur`` when the caller has it."""
        labels = self._check_frame(frame, self.k)
        rng = np.random.default_rng(_frame_seed(self.seed, frame))
        if band is None:
            band, _ = boundary_band(labels, self.boundary_blur)
        (u_err,) = self._uniforms(rng, frame, labels.shape, 1)
        return ~self._correct(u_err, labels, band) & (labels != VOID)

    def _check_frame(self, frame: Frame, k: int) -> np.ndarray:
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
        return labels

    def predict(self, frame: Frame, *, k: int | None = None) -> SemanticObservation:
        k = self.k if k is None else int(k)
        labels = self._check_frame(frame, k)
        void = labels == VOID
        c = self.num_classes
        rng = np.random.default_rng(_frame_seed(self.seed, frame))
        if self.confusion == "adjacent":
            table, weights = self._adjacent_confusers(labels)
        else:
            table, weights = self.confusers, self.confuser_weights
        m = table.shape[1]
        true = np.where(void, 0, labels).astype(np.intp)
        band, across = boundary_band(labels, self.boundary_blur)

        # Top-1: correct or a wrong class. Confuser j of the true class is picked when the
        # uniform falls in [cum_{j-1}, cum_j) of its weights.
        u_err, u_pick, u_second = self._uniforms(rng, frame, labels.shape)
        correct = self._correct(u_err, labels, band)
        cum = np.cumsum(weights, axis=1)[true]  # (H, W, m)
        options = table.astype(np.int32)[true]  # (H, W, m)
        pick = np.minimum((u_pick[..., None] >= cum).sum(axis=2), m - 1)
        confuser = np.take_along_axis(options, pick[..., None], axis=2)[..., 0]
        bleeds = band & (across >= 0)
        if self.profile.boundary_across < 1.0:
            extra = np.random.default_rng(_frame_seed(self.seed, frame, _FIELD_SALT, 1))
            bleeds &= extra.random(labels.shape) < self.profile.boundary_across
        wrong = np.where(bleeds, across, confuser)
        random_cls = rng.integers(0, c, size=(3,) + labels.shape, dtype=np.int32)
        top1 = np.where(void, random_cls[0], np.where(correct, true, wrong)).astype(np.int32)

        # Slots 2..k: candidate list, duplicates removed, first k kept.
        pick2 = np.minimum((u_second[..., None] >= cum).sum(axis=2), m - 1)
        second = np.take_along_axis(options, pick2[..., None], axis=2)[..., 0]
        true_second = rng.random(labels.shape) < self.profile.true_second
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
        probs = self._probabilities(rng, labels.shape, void, band, correct, k)
        return SemanticObservation(classes=classes.astype(np.int16), probs=probs,
                                   num_classes=c)

    def _probabilities(self, rng: np.random.Generator, shape: tuple[int, ...], void: np.ndarray,
                       band: np.ndarray, correct: np.ndarray, k: int) -> np.ndarray:
        """(H, W, k) non-increasing probabilities (module notes)."""
        mean_top1 = self.profile.mean_top1
        mean = np.select(
            [void, band & correct, band, correct],
            [mean_top1["void"], mean_top1["edge_correct"], mean_top1["edge_wrong"],
             mean_top1["correct"]], default=mean_top1["wrong"])
        concentration = self.profile.concentration
        p1 = rng.beta(mean * concentration, (1.0 - mean) * concentration)
        p1 = np.clip(p1, 0.05, 0.995)
        probs = np.empty(shape + (k,), dtype=np.float64)
        probs[..., 0] = p1
        if k > 1:
            keep = rng.uniform(0.75, 0.98, size=shape)
            w = 0.55 ** np.arange(1, k) * rng.uniform(0.7, 1.3, size=shape + (k - 1,))
            w = -np.sort(-w, axis=2)
            w /= w.sum(axis=2, keepdims=True)
            probs[..., 1:] = ((1.0 - p1) * keep)[..., None] * w
        return np.minimum.accumulate(probs.astype(np.float32), axis=2)


@SEGMENTERS.register(
    "oracle",
    takes=Takes(),  # not a network: no weights, backend or input size
    description="Ground-truth labels with a network's kind of errors (profile: fitted, "
                "per-pixel, noise-free or a file)",
)
def oracle(
    *,
    profile: str = DEFAULT_PROFILE,
    num_classes: int = 40,
    accuracy: float | None = None,
    confusion: str | None = None,
    boundary_blur: int | None = None,
    boundary_accuracy: float | None = None,
    error_block: int | None = None,
    error_scale: float | None = None,
    world_share: float | None = None,
    seed: int = 0,
    k: int = 3,
) -> OracleSegmenter:
    """Noisy top-k predictions from ground-truth labels (needs labelled frames); an option
    given replaces the profile's value (None: the profile's)."""
    return OracleSegmenter(profile=profile, num_classes=num_classes, seed=seed, k=k,
                           accuracy=accuracy, confusion=confusion, boundary_blur=boundary_blur,
                           boundary_accuracy=boundary_accuracy, error_block=error_block,
                           error_scale=error_scale, world_share=world_share)
