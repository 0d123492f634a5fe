"""Fit the oracle to a segmenter: ``evsmap oracle fit`` (docs/oracle.md).

1. **The segmenter's errors**: it segments labelled frames and
   :class:`~evsmap.metrics.label_errors.LabelErrorStats` measures how it errs (error rates in the
   interior and at boundaries, per class; which classes it takes each for; how its errors
   cluster in the image and persist from frame to frame; its confidence when right and wrong).
2. **Direct values**: the oracle's accuracies (overall and per class with enough pixels), its
   confusers (each class's three most frequent mistakes), the share of wrong pixels whose second
   class is the true one, and the top-1 probability's means and Beta concentration are read off
   those figures.
3. **The error field by simulation**: ``error_scale``, ``world_share`` and ``world_scale`` are
   chosen by coordinate descent over :data:`GRID`, each candidate's errors drawn on the same
   frames (:meth:`~evsmap.segmenters.oracle.OracleSegmenter.error_mask`) and scored by the
   squared difference of the error autocorrelation at every lag plus twice that of the
   frame-to-frame persistence; then ``boundary_across`` so the share of band errors that take a
   label within the window matches.
4. **The check**: the fitted oracle's full predictions on all the frames, measured like the
   segmenter's; both sets of figures go in the profile's ``fit``.

Without poses in one world (single images, e.g. NYUv2) persistence cannot be measured: the fit
keeps ``world_share`` at 0 and says so.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from typing import Any

import numpy as np

from evsmap.data import Sequence
from evsmap.interfaces import Segmenter
from evsmap.metrics.label_errors import LAGS, LabelErrorStats
from evsmap.segmenters.oracle import OracleSegmenter
from evsmap.segmenters.oracle_field import FieldMemo
from evsmap.segmenters.oracle_profile import DEFAULT_PROFILE, OracleProfile, load_profile

FIT_SCENES = (("bedroom", 1), ("office", 2), ("kitchen", 3))
"""The default fit frames: these synthetic rooms (scene, seed), 60 frames each at 640x480 with
Kinect-like depth noise - not the living room (seed 0) the benchmark maps, so the check on the
benchmark's room is not made on the frames the fit saw."""
FIT_FRAMES = 60
SEARCH_FRAMES = 20
"""Frames per sequence (the first, consecutive) each candidate of the field search draws."""
MIN_INTERIOR_PIXELS = 20_000
MIN_BAND_PIXELS = 5_000
"""A class gets its own interior / boundary accuracy with at least this many pixels."""
GRID: dict[str, tuple[float, ...]] = {
    "error_scale": (0.0, 1.0, 2.0, 4.0, 8.0, 16.0, 32.0, 64.0),
    "world_share": (0.0, 0.2, 0.4, 0.6, 0.8, 0.9, 0.95, 1.0),
    "world_scale": (0.05, 0.1, 0.2, 0.4),
}
START = {"error_scale": 4.0, "world_share": 0.4, "world_scale": 0.2}
PASSES = 2
PERSISTENCE_WEIGHT = 2.0

Say = Callable[[str], None]


def fit_sequences(frames: int = FIT_FRAMES) -> list[Sequence]:
    """The default fit frames (:data:`FIT_SCENES`), rendered once into the cache."""
    from evsmap.registry import READERS

    return [READERS.create("synthetic", scene=scene, seed=seed, frames=frames, width=640,
                           height=480, noise=True, render="cached")
            for scene, seed in FIT_SCENES]


def one_world(sequence: Sequence) -> bool:
    """Whether the sequence's poses share one world (so consecutive frames can be paired)."""
    return sequence.meta.get("poses", True) is not False


def measure_errors(segmenter: Segmenter, sequences: Iterable[Sequence], *, radius: int = 3,
                   frames: int | None = None, say: Say | None = None) -> dict[str, Any]:
    """How ``segmenter`` errs on the labelled frames of ``sequences`` (the first ``frames`` of
    each): :meth:`LabelErrorStats.result`."""
    stats = LabelErrorStats(segmenter.num_classes, radius=radius)
    for seq in sequences:
        n = len(seq) if frames is None else min(frames, len(seq))
        paired = one_world(seq)
        stats.new_sequence()  # never pair frames of two sequences
        for i in range(n):
            frame = seq.frame(i)
            stats.add(frame, segmenter.predict(frame), same_world=paired)
        if say:
            say(f"  {seq.name}: {n} frames")
    return stats.result()


def _class_values(stats: dict[str, Any], key: str, pixels: str, least: int) -> dict[int, float]:
    return {int(c): round(1.0 - v[key], 4) for c, v in stats["classes"].items()
            if v[key] is not None and v[pixels] >= least}


def _concentration(probs: dict[str, Any]) -> float:
    """The Beta concentration that matches the pooled variance of the top-1 probability over
    the labelled kinds (method of moments, pixel-weighted)."""
    num = den = 0.0
    for kind in ("correct", "wrong", "edge_correct", "edge_wrong"):
        m = probs[kind]
        if m["mean"] is None or not m["var"]:
            continue
        num += m["pixels"] * (m["mean"] * (1 - m["mean"]) / m["var"] - 1.0)
        den += m["pixels"]
    return float(np.clip(num / den, 1.0, 200.0)) if den else 12.0


def direct_profile(stats: dict[str, Any], *, name: str, source: str,
                   base: OracleProfile | None = None) -> OracleProfile:
    """The values read off the segmenter's figures (module notes, step 2)."""
    base = base or load_profile("per-pixel")
    probs = stats["top1_probability"]
    means = {k: float(np.clip(v["mean"], 0.02, 0.98)) if v["mean"] is not None
             else base.mean_top1[k] for k, v in probs.items()}
    confusers = {}
    for cls, v in stats["classes"].items():
        pairs = [(int(o), float(n)) for o, n in v["taken_for"] if n > 0]
        if pairs:
            total = sum(n for _, n in pairs)
            confusers[int(cls)] = [(o, round(n / total, 4)) for o, n in pairs]
    return base.replace(
        name=name, source=source,
        accuracy=round(1.0 - stats["interior_error"], 4),
        boundary_accuracy=round(1.0 - stats["band_error"], 4),
        boundary_blur=stats["radius"],
        class_accuracy=_class_values(stats, "interior_error", "interior_pixels",
                                     MIN_INTERIOR_PIXELS),
        class_boundary_accuracy=_class_values(stats, "band_error", "band_pixels",
                                              MIN_BAND_PIXELS),
        confusion="fitted" if confusers else base.confusion, confusers=confusers,
        true_second=round(stats["true_second"], 4) if stats["true_second"] is not None
        else base.true_second,
        mean_top1={k: round(v, 4) for k, v in means.items()},
        concentration=round(_concentration(probs), 2), fit={})


def pattern_loss(target: dict[str, Any], trial: dict[str, Any]) -> float:
    """Squared differences of the error autocorrelation (every lag) and persistence."""
    loss = 0.0
    for d in LAGS:
        a, b = target["autocorrelation"][str(d)], trial["autocorrelation"][str(d)]
        if a is not None and b is not None:
            loss += (a - b) ** 2
    pa, pb = target["persistence"], trial["persistence"]
    if pa is not None and pb is not None:
        loss += PERSISTENCE_WEIGHT * (pa - pb) ** 2
    return loss


class SearchMemo:
    """What every candidate of the field search shares: the frames, the oracle's fields and the
    frames' geometry (boundary bands, matched pixels)."""

    def __init__(self, sequences: list[Sequence], frames: int) -> None:
        self.frames = [[seq.frame(i) for i in range(min(frames, len(seq)))] for seq in sequences]
        self.paired = [one_world(seq) for seq in sequences]
        self.fields = FieldMemo()
        self.geometry: dict[tuple[object, ...], Any] = {}


def error_pattern(profile: OracleProfile, memo: SearchMemo, *, seed: int = 0) -> dict[str, Any]:
    """The oracle's error figures (rates, autocorrelation, patches, persistence) on the memo's
    frames, from its error masks alone."""
    oracle = OracleSegmenter(profile=profile, seed=seed, memo=memo.fields)
    stats = LabelErrorStats(oracle.num_classes, radius=profile.boundary_blur,
                            memo=memo.geometry)
    for seq_frames, same_world in zip(memo.frames, memo.paired, strict=True):
        stats.new_sequence()
        for frame in seq_frames:
            wrong = oracle.error_mask(frame, stats.band(frame))
            stats.add_errors(frame, wrong, same_world=same_world)
    return stats.result()


def search_field(profile: OracleProfile, sequences: list[Sequence], target: dict[str, Any], *,
                 frames: int = SEARCH_FRAMES, say: Say | None = None
                 ) -> tuple[OracleProfile, list[dict[str, Any]]]:
    """Coordinate descent over :data:`GRID` (module notes, step 3); the trace of every
    candidate tried, with its loss."""
    names = list(GRID) if target["persistence"] is not None else ["error_scale"]
    current = dict(START)
    if target["persistence"] is None:
        current["world_share"] = 0.0
    trace: list[dict[str, Any]] = []
    seen: dict[tuple[float, ...], float] = {}
    memo = SearchMemo(sequences, frames)

    def loss_of(settings: dict[str, float]) -> float:
        key = tuple(settings[n] for n in GRID)
        if key not in seen:
            trial = error_pattern(profile.replace(**settings), memo)
            seen[key] = pattern_loss(target, trial)
            trace.append({**settings, "loss": round(seen[key], 6),
                          "persistence": trial["persistence"],
                          "autocorrelation_4": trial["autocorrelation"]["4"]})
            if say:
                say(f"  {', '.join(f'{n}={v:g}' for n, v in settings.items())}: "
                    f"loss {seen[key]:.4f}")
        return seen[key]

    for _ in range(PASSES):
        for name in names:
            if name == "world_scale" and current["world_share"] == 0.0:
                continue
            best = min(GRID[name], key=lambda v: loss_of({**current, name: v}))
            current[name] = best
    return profile.replace(**current), trace


def fit_across(profile: OracleProfile, sequences: list[Sequence], target: dict[str, Any],
               frames: int) -> OracleProfile:
    """``boundary_across``: the share of band errors that bleed across, so that with the
    confusers' chance hits the share taking a label within the window is the segmenter's."""
    share = target["band_errors_in_window"]
    if share is None:
        return profile
    oracle = OracleSegmenter(profile=profile.replace(boundary_across=0.0))
    chance = measure_errors(oracle, sequences, radius=profile.boundary_blur,
                            frames=frames)["band_errors_in_window"] or 0.0
    across = 1.0 if chance >= 1.0 else (share - chance) / (1.0 - chance)
    return profile.replace(boundary_across=round(float(np.clip(across, 0.0, 1.0)), 4))


def summary(stats: dict[str, Any]) -> dict[str, Any]:
    """The figures the docs and ``evsmap oracle show`` print (no per-class tables)."""
    keys = ("frames", "radius", "pixels", "interior_error", "band_error", "pixel_error",
            "band_errors_in_window", "interior_errors_touching", "autocorrelation",
            "patch_area", "persistence", "persistence_pairs", "true_second")
    out = {k: stats[k] for k in keys}
    out["top1_probability"] = {k: v["mean"] for k, v in stats["top1_probability"].items()}
    out["class_accuracy_spread"] = _spread(stats)
    return out


def _spread(stats: dict[str, Any]) -> dict[str, Any]:
    accs = sorted(1.0 - v["interior_error"] for v in stats["classes"].values()
                  if v["interior_error"] is not None
                  and v["interior_pixels"] >= MIN_INTERIOR_PIXELS)
    if not accs:
        return {"classes": 0}
    return {"classes": len(accs), "min": accs[0], "median": accs[len(accs) // 2],
            "max": accs[-1]}


def fit_oracle(segmenter: Segmenter, sequences: list[Sequence], *, about: dict[str, Any],
               name: str = DEFAULT_PROFILE, frames: int | None = None,
               search_frames: int = SEARCH_FRAMES, radius: int = 3,
               say: Say | None = None) -> OracleProfile:
    """The oracle profile fitted to ``segmenter`` on ``sequences`` (module notes). ``about``
    (the segmenter, its weights, the frames) goes in the profile's ``fit`` and ``source``."""
    say = say or (lambda _: None)
    say(f"measuring {about.get('segmenter', 'the segmenter')} on {len(sequences)} sequences")
    target = measure_errors(segmenter, sequences, radius=radius, frames=frames, say=say)
    source = (f"fitted to {about.get('segmenter')} (weights {about.get('weights')}) on "
              f"{target['frames']} labelled frames of {about.get('frames_from')}")
    profile = direct_profile(target, name=name, source=source)
    say(f"searching the error field ({search_frames} frames of each sequence per candidate)")
    profile, trace = search_field(profile, sequences, target, frames=search_frames, say=say)
    profile = fit_across(profile, sequences, target, frames=search_frames)
    say("checking the fitted oracle on every frame")
    check = measure_errors(OracleSegmenter(profile=profile), sequences, radius=radius,
                           frames=frames)
    fit = {**about, "network": summary(target), "oracle": summary(check), "search": trace,
           "loss": round(pattern_loss(target, check), 6),
           "persistence_measured": target["persistence"] is not None}
    return profile.replace(fit=_finite(fit))


def _finite(value: Any) -> Any:
    """JSON-safe: NaN and infinities as None, numpy scalars as Python numbers."""
    if isinstance(value, dict):
        return {str(k): _finite(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite(v) for v in value]
    if isinstance(value, (np.floating, float)):
        f = float(value)
        return round(f, 6) if math.isfinite(f) else None
    if isinstance(value, np.integer):
        return int(value)
    return value


__all__ = ["FIT_SCENES", "GRID", "direct_profile", "error_pattern", "fit_oracle",
           "fit_sequences", "measure_errors", "pattern_loss", "search_field", "summary"]
