"""How a segmenter errs on labelled frames: the figures the oracle is fitted to.

:class:`LabelErrorStats` takes frames with their ground-truth labels and a segmenter's
observations and accumulates, over the labelled pixels (void excluded):

* the top-1 error rate in the interior and in the boundary band (pixels within ``radius`` px,
  Chebyshev, of a label change: :func:`boundary_band`, the oracle's own band), per class and
  overall;
* the share of the band's errors that take a label present within the window (the region
  across the boundary bleeding in), and of the interior's errors that take a class touching the
  true class in the frame;
* the interior confusion (true class, predicted class) counts: which classes each is taken for;
* the spatial autocorrelation of the error indicator at lags of 1-64 px (horizontal and vertical
  pairs of labelled pixels, lags in px of a 640 px wide frame), and the size of the error patch a
  wrong pixel lies in (8-connected, area-weighted mean, px at 640 px width);
* the persistence of errors from frame to frame: the correlation (phi) of the error indicator of
  the same surface point in consecutive frames (each frame's pixels projected into the previous
  frame with depth and poses, kept where the depths agree within 5 %), where the frames share one
  world;
* the top-1 probability's mean and variance when right and when wrong, inside and in the band,
  on void; how often a wrong pixel's second class is its true class.

:meth:`LabelErrorStats.result` returns a plain dict (fractions, pixels, counts).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from evsmap.data import VOID, Frame, SemanticObservation

LAGS = (1, 2, 4, 8, 16, 32, 64)
"""Autocorrelation lags, px at 640 px width."""
REFERENCE_WIDTH = 640
"""Lags, patch areas and the oracle's ``error_scale`` are in px of a frame this wide."""
PAIR_STRIDE = 2
"""Every second row and column is projected for the frame-to-frame persistence."""
DEPTH_AGREEMENT = 0.05
KINDS = ("correct", "wrong", "edge_correct", "edge_wrong", "void")


def window_extreme(a: np.ndarray, r: int, fn: Any) -> np.ndarray:
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


def boundary_band(labels: np.ndarray, r: int) -> tuple[np.ndarray, np.ndarray]:
    """The labelled pixels within ``r`` px (Chebyshev) of a label change (void counts as a
    label), and per pixel the label across it: the largest other label in the window, else the
    smallest, else -1."""
    void = labels == VOID
    if r <= 0:
        return np.zeros(labels.shape, dtype=bool), np.full(labels.shape, -1, dtype=np.int16)
    band = window_extreme(labels, r, np.maximum) != window_extreme(labels, r, np.minimum)
    lab = labels.astype(np.int16)
    true = np.where(void, 0, labels).astype(np.intp)
    hi = window_extreme(np.where(void, -1, lab), r, np.maximum)
    lo = window_extreme(np.where(void, 999, lab), r, np.minimum)
    across = np.where((hi != true) & (hi >= 0), hi, np.where((lo != true) & (lo < 999), lo, -1))
    return band & ~void, across


def _in_window(labels: np.ndarray, values: np.ndarray, r: int) -> np.ndarray:
    """Whether ``values`` occurs among ``labels`` within ``r`` px (Chebyshev) of each pixel."""
    h, w = labels.shape
    padded = np.pad(labels, r, mode="constant", constant_values=VOID)
    found = np.zeros(labels.shape, dtype=bool)
    for dy in range(2 * r + 1):
        for dx in range(2 * r + 1):
            found |= padded[dy:dy + h, dx:dx + w] == values
    return found


def _touching(labels: np.ndarray, c: int) -> np.ndarray:
    """(C, C) whether two classes share a 4-neighbour edge in the frame."""
    contact = np.zeros((c, c), dtype=bool)
    for a, b in ((labels[:, :-1], labels[:, 1:]), (labels[:-1, :], labels[1:, :])):
        keep = (a != b) & (a != VOID) & (b != VOID)
        contact[a[keep].astype(np.intp), b[keep].astype(np.intp)] = True
    return contact | contact.T


def matched_pixels(f0: Frame, f1: Frame) -> tuple[np.ndarray, np.ndarray]:
    """Flat pixel indices (in ``f0``, in ``f1``) of the same surface point: every
    :data:`PAIR_STRIDE`-th labelled pixel of ``f1`` with depth, projected into ``f0``, kept where
    it lands on a labelled pixel whose depth agrees within :data:`DEPTH_AGREEMENT`."""
    assert f0.depth is not None and f0.intrinsics is not None and f0.labels is not None
    assert f1.depth is not None and f1.intrinsics is not None and f1.labels is not None
    s = PAIR_STRIDE
    h1, w1 = f1.depth.shape
    v, u = np.mgrid[0:h1:s, 0:w1:s]
    depth1 = np.asarray(f1.depth, dtype=np.float64)[v, u]
    ok = np.isfinite(depth1) & (depth1 > 0) & (f1.labels[v, u] != VOID)
    k1, k0 = f1.intrinsics, f0.intrinsics
    d, uu, vv = depth1[ok], u[ok].astype(np.float64), v[ok].astype(np.float64)
    cam = np.stack([(uu - k1.cx) / k1.fx * d, (vv - k1.cy) / k1.fy * d, d], -1)
    world = cam @ np.asarray(f1.pose)[:3, :3].T + np.asarray(f1.pose)[:3, 3]
    inv = np.linalg.inv(np.asarray(f0.pose, dtype=np.float64))
    c0 = world @ inv[:3, :3].T + inv[:3, 3]
    z = c0[:, 2]
    h0, w0 = f0.depth.shape
    with np.errstate(divide="ignore", invalid="ignore"):
        x = np.round(np.where(z > 0, c0[:, 0] / z * k0.fx + k0.cx, -1.0))
        y = np.round(np.where(z > 0, c0[:, 1] / z * k0.fy + k0.cy, -1.0))
    inside = (z > 0) & (x >= 0) & (x < w0) & (y >= 0) & (y < h0)
    x, y, z = x[inside].astype(np.int64), y[inside].astype(np.int64), z[inside]
    d0 = np.asarray(f0.depth, dtype=np.float64)[y, x]
    seen = (d0 > 0) & (np.abs(d0 - z) <= DEPTH_AGREEMENT * z) & (f0.labels[y, x] != VOID)
    flat1 = (v[ok] * w1 + u[ok])[inside][seen]
    return y[seen] * w0 + x[seen], flat1


class LabelErrorStats:
    """Accumulates the error figures of one segmenter over frames (module notes)."""

    def __init__(self, num_classes: int, *, radius: int = 3,
                 memo: dict[tuple[object, ...], Any] | None = None) -> None:
        self.c = int(num_classes)
        self.radius = int(radius)
        self.memo = memo
        """Per-frame geometry kept across instances (boundary bands, matched pixels): for a
        caller that measures the same frames many times (the oracle's fit)."""
        self.reset()

    def band(self, frame: Frame) -> np.ndarray:
        """The frame's boundary band (:func:`boundary_band`), from the memo when kept."""
        assert frame.labels is not None
        key = ("band", frame.name, frame.timestamp, self.radius)
        if self.memo is not None and key in self.memo:
            return self.memo[key]
        band, _ = boundary_band(frame.labels, self.radius)
        if self.memo is not None:
            self.memo[key] = band
        return band

    def reset(self) -> None:
        c = self.c
        self.n = np.zeros((2, c), dtype=np.int64)  # [interior, band] pixels per class
        self.err = np.zeros((2, c), dtype=np.int64)
        self.confusion = np.zeros((c, c), dtype=np.int64)  # interior (true, top-1)
        self.band_in_window = 0
        self.interior_touching = 0
        self.lag = {d: np.zeros(4, dtype=np.float64) for d in LAGS}  # pairs, a, b, both
        self.patch = np.zeros(2, dtype=np.float64)  # sum of area^2, sum of area
        self.persist = np.zeros(4, dtype=np.float64)  # pairs, prev, cur, both
        self.prob = {k: np.zeros(3, dtype=np.float64) for k in KINDS}  # n, sum, sum of squares
        self.second = np.zeros(2, dtype=np.int64)  # wrong pixels with k >= 2, true second
        self.frames = 0
        self._previous: tuple[Frame, np.ndarray] | None = None

    def new_sequence(self) -> None:
        """The next frame starts another sequence: it is not paired with the previous one."""
        self._previous = None

    # -- per frame ------------------------------------------------------------------------------
    def add(self, frame: Frame, observation: SemanticObservation, *,
            same_world: bool = False) -> None:
        """One frame's labels and observation; ``same_world``: its pose is in the previous
        frame's world (a sequence with poses), so their errors are paired."""
        labels = frame.labels
        if labels is None:
            raise ValueError(f"frame {frame.name!r} has no labels")
        top1 = observation.classes[..., 0].astype(np.intp)
        p1 = observation.probs[..., 0].astype(np.float64)
        void = labels == VOID
        true = np.where(void, 0, labels).astype(np.intp)
        band = self.band(frame)
        wrong = ~void & (top1 != true)
        for i, region in enumerate((~void & ~band, band)):
            self.n[i] += np.bincount(true[region], minlength=self.c)[: self.c]
            self.err[i] += np.bincount(true[region & wrong], minlength=self.c)[: self.c]
        inner_wrong = wrong & ~band
        np.add.at(self.confusion, (true[inner_wrong], top1[inner_wrong]), 1)
        edge_wrong = wrong & band
        across = _in_window(labels.astype(np.int16), np.where(edge_wrong, top1, -1), self.radius)
        self.band_in_window += int(np.count_nonzero(across & edge_wrong))
        touch = _touching(labels, self.c)
        ok = top1[inner_wrong] < self.c
        self.interior_touching += int(touch[true[inner_wrong][ok], top1[inner_wrong][ok]].sum())
        self._add_probs(p1, void, band, wrong)
        if observation.classes.shape[-1] > 1:
            self.second[0] += int(np.count_nonzero(wrong))
            self.second[1] += int(np.count_nonzero(wrong & (observation.classes[..., 1] == true)))
        self._add_pattern(frame, wrong, same_world)

    def add_errors(self, frame: Frame, wrong: np.ndarray, *, same_world: bool = False) -> None:
        """Only where a frame's errors lie (``wrong``: the labelled pixels whose top-1 is
        wrong): the error rates, their autocorrelation, patches and persistence, without an
        observation (the other figures stay as they are)."""
        labels = frame.labels
        if labels is None:
            raise ValueError(f"frame {frame.name!r} has no labels")
        void = labels == VOID
        true = np.where(void, 0, labels).astype(np.intp)
        band = self.band(frame)
        for i, region in enumerate((~void & ~band, band)):
            self.n[i] += np.bincount(true[region], minlength=self.c)[: self.c]
            self.err[i] += np.bincount(true[region & wrong], minlength=self.c)[: self.c]
        self._add_pattern(frame, wrong & ~void, same_world)

    def _add_pattern(self, frame: Frame, wrong: np.ndarray, same_world: bool) -> None:
        assert frame.labels is not None
        self._add_space(wrong, frame.labels != VOID)
        if same_world and self._previous is not None:
            self._add_persistence(self._previous, (frame, wrong))
        self._previous = (frame, wrong)
        self.frames += 1

    def _add_space(self, wrong: np.ndarray, valid: np.ndarray) -> None:
        scale = wrong.shape[1] / REFERENCE_WIDTH
        for d in LAGS:
            s = max(1, int(round(d * scale)))
            for a, b, va, vb in ((wrong[:, :-s], wrong[:, s:], valid[:, :-s], valid[:, s:]),
                                 (wrong[:-s], wrong[s:], valid[:-s], valid[s:])):
                both = va & vb
                self.lag[d] += [both.sum(), (a & both).sum(), (b & both).sum(),
                                (a & b & both).sum()]
        from scipy import ndimage  # scipy only when measuring (`evsmap list` stays light)

        components, count = ndimage.label(wrong, structure=np.ones((3, 3)))
        if count:
            area = np.bincount(components.ravel())[1:].astype(np.float64) / scale ** 2
            self.patch += [(area ** 2).sum(), area.sum()]

    def _add_probs(self, p1: np.ndarray, void: np.ndarray, band: np.ndarray,
                   wrong: np.ndarray) -> None:
        right = ~void & ~wrong
        masks = {"correct": right & ~band, "wrong": wrong & ~band, "edge_correct": right & band,
                 "edge_wrong": wrong & band, "void": void}
        for kind, mask in masks.items():
            v = p1[mask]
            self.prob[kind] += [v.size, v.sum(), (v * v).sum()]

    def _add_persistence(self, previous: tuple[Frame, np.ndarray],
                         current: tuple[Frame, np.ndarray]) -> None:
        (f0, wrong0), (f1, wrong1) = previous, current
        key = (f0.name, f0.timestamp, f1.name, f1.timestamp)
        if self.memo is None or key not in self.memo:
            pairs = matched_pixels(f0, f1)
            if self.memo is not None:
                self.memo[key] = pairs
        else:
            pairs = self.memo[key]
        a, b = wrong0.ravel()[pairs[0]], wrong1.ravel()[pairs[1]]
        self.persist += [a.size, a.sum(), b.sum(), (a & b).sum()]

    # -- result ---------------------------------------------------------------------------------
    def result(self) -> dict[str, Any]:
        """The figures (module notes) as a plain dict; fractions, not percent."""
        def rate(e: np.ndarray | int, n: np.ndarray | int) -> float | None:
            return float(e) / float(n) if n else None

        n_in, n_band = int(self.n[0].sum()), int(self.n[1].sum())
        e_in, e_band = int(self.err[0].sum()), int(self.err[1].sum())
        per_class = {}
        for cls in np.flatnonzero(self.n.sum(axis=0)):
            row = self.confusion[cls].copy()
            row[cls] = 0
            top = np.argsort(-row, kind="stable")[:3]
            per_class[int(cls)] = {
                "interior_pixels": int(self.n[0, cls]), "band_pixels": int(self.n[1, cls]),
                "interior_error": rate(self.err[0, cls], self.n[0, cls]),
                "band_error": rate(self.err[1, cls], self.n[1, cls]),
                "taken_for": [[int(o), int(row[o])] for o in top if row[o] > 0]}
        return {
            "frames": self.frames, "radius": self.radius,
            "pixels": {"interior": n_in, "band": n_band},
            "interior_error": rate(e_in, n_in), "band_error": rate(e_band, n_band),
            "pixel_error": rate(e_in + e_band, n_in + n_band),
            "band_errors_in_window": rate(self.band_in_window, e_band),
            "interior_errors_touching": rate(self.interior_touching, e_in),
            "autocorrelation": {str(d): _phi(*self.lag[d]) for d in LAGS},
            "patch_area": None if not self.patch[1] else float(self.patch[0] / self.patch[1]),
            "persistence": _phi(*self.persist),
            "persistence_pairs": int(self.persist[0]),
            "top1_probability": {k: _moments(*self.prob[k]) for k in KINDS},
            "true_second": rate(self.second[1], self.second[0]),
            "classes": per_class,
        }


def _phi(pairs: float, a: float, b: float, both: float) -> float | None:
    """The correlation of two binary variables from pair counts (None without variance)."""
    if pairs <= 0:
        return None
    pa, pb, pab = a / pairs, b / pairs, both / pairs
    den = pa * (1 - pa) * pb * (1 - pb)
    return None if den <= 0 else float((pab - pa * pb) / np.sqrt(den))


def _moments(n: float, s: float, s2: float) -> dict[str, float | None]:
    if n <= 0:
        return {"pixels": 0, "mean": None, "var": None}
    mean = s / n
    return {"pixels": int(n), "mean": float(mean), "var": float(max(s2 / n - mean * mean, 0.0))}


__all__ = ["LAGS", "LabelErrorStats", "boundary_band", "matched_pixels", "window_extreme"]
