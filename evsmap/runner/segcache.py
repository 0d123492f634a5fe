"""On-disk cache of segmentation outputs and timings, shared by the cells of one run.

* Observations (per-frame top-k classes and probabilities) are computed once per (segmenter
  configuration, weights file, sequence, frames) and stored as one ``.npz`` per frame, so every
  updater of Table IV maps the same labels and none pays for segmentation again.
* The observations' bytes depend on nothing but the frames, the segmenter's configuration and
  weights and, for a network, its intra-op thread count (its logits change in their last bits
  with it; docs/cli.md, "Thread independence"), recorded as ``network_threads`` in the entry's
  ``meta.json``. The thread count is not part of the key: the first cell to compute an entry
  fixes the bytes every later cell of the run maps, whichever machine or executor it runs on.
* Segmentation times (ms per frame) of a network are stored next to them: when no trained weights
  are given, mapping uses the oracle's labels and the untrained network is only timed (its speed
  does not depend on its weights), which is what the segmentation + update rate needs. It is
  timed on the sequence's frames in order under the run's timing policy (until its median is
  precise enough or its budget is spent), not on every frame.

Entries are keyed by a hash of everything that determines them and written atomically (a
temporary folder renamed into place), so an interrupted run never leaves half an entry.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from evsmap.data import SemanticObservation, Sequence
from evsmap.interfaces import Segmenter
from evsmap.measure.engine import run_segmentation
from evsmap.measure.evaluators import KeepObservations
from evsmap.measure.timing_policy import TimingPolicy, time_until_precise


def cache_key(**parts: Any) -> str:
    text = json.dumps(parts, sort_keys=True, default=str)
    return hashlib.sha1(text.encode()).hexdigest()[:16]


class SegmentationCache:
    """Observations and timings under ``root`` (``<run>/cache/segmentation``)."""

    def __init__(self, root: str | os.PathLike[str]) -> None:
        self.root = Path(root)

    def _entry(self, kind: str, key: str) -> Path:
        return self.root / f"{kind}-{key}"

    def _publish(self, tmp: Path, final: Path) -> None:
        try:
            os.replace(tmp, final)
        except OSError:  # another process published the same entry first
            shutil.rmtree(tmp, ignore_errors=True)

    def observations(self, segmenter: Segmenter, sequence: Sequence, indices: list[int], *,
                     key: dict[str, Any], progress: Callable[[Any], Any] | None = None
                     ) -> tuple[list[SemanticObservation], list[float], bool]:
        """The observations of ``segmenter`` on ``sequence``'s frames ``indices`` (computed and
        stored on the first call), the time of each prediction in ms when computed, and whether
        they came from the cache."""
        entry = self._entry("obs", cache_key(indices=indices, **key))
        if (entry / "meta.json").is_file():
            meta = json.loads((entry / "meta.json").read_text())
            obs = []
            for i in range(len(indices)):
                with np.load(entry / f"{i:05d}.npz") as z:
                    obs.append(SemanticObservation(classes=z["classes"], probs=z["probs"],
                                                   num_classes=int(z["num_classes"])))
            return obs, meta["predict_ms"], True
        self.root.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(dir=self.root, prefix=".tmp-obs-"))
        try:
            def store(n: int, o: SemanticObservation) -> None:
                np.savez(tmp / f"{n:05d}.npz", classes=o.classes, probs=o.probs,
                         num_classes=o.num_classes)

            seg = run_segmentation(sequence, segmenter, indices=indices, progress=progress,
                                   evaluators=[KeepObservations(sink=store)])
            obs, times = seg.results["observations"], seg.predict_ms
            (tmp / "meta.json").write_text(json.dumps(
                {"key": key, "indices": indices, "predict_ms": times,
                 "network_threads": segmenter.network_threads}, default=str))
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
        self._publish(tmp, entry)
        return obs, times, False

    def timings(self, segmenter: Segmenter, sequence: Sequence, indices: list[int], *,
                key: dict[str, Any], policy: TimingPolicy) -> tuple[dict[str, Any], bool]:
        """ms per ``predict`` of ``segmenter`` on ``sequence``'s frames ``indices`` in order
        (cycling when the policy wants more passes than frames), timed under ``policy``
        (:func:`~evsmap.measure.timing_policy.time_until_precise`) and stored; returns the
        timing (``predict_ms``, ``rel_ci``, ``stopped``, ``warmup``) and whether it came from
        the cache."""
        entry = self._entry("time", cache_key(indices=indices, policy=policy.as_dict(), **key))
        if (entry / "meta.json").is_file():
            meta = json.loads((entry / "meta.json").read_text())
            return {k: v for k, v in meta.items() if k not in ("key", "indices")}, True
        self.root.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(dir=self.root, prefix=".tmp-time-"))
        try:
            passes = time_until_precise(
                segmenter.predict, policy,
                setup=lambda i: sequence.frame(indices[i % len(indices)]))
            times = {"predict_ms": [t * 1000.0 for t in passes.times_s],
                     "rel_ci": passes.rel_ci, "stopped": passes.stopped,
                     "warmup": passes.warmup_runs, "policy": passes.policy}
            (tmp / "meta.json").write_text(json.dumps(
                {"key": key, "indices": indices, **times}, default=str))
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
        self._publish(tmp, entry)
        return times, False
