"""One trial of a study, measured the way Table IV measures a map (:func:`run_mapping`, the map's
three size readings, its 3D quality against the sequence's ground-truth voxels), in one process:

1. the explored updater at the trial's parameters maps the frames (each update timed);
2. the reference (OctoMap C++) maps the same frames at the same resolution and max range, timed
   right after in the same process: ``rate_ratio`` = the trial's ``update_hz`` over the
   reference's, a figure that does not move with the machine's speed;
3. the map is scored against the ground truth (untimed);
4. the paired baseline (Table IV's TESAMap update) at the same shared settings, with the same
   observations: its sizes and 3D quality are exact, so they come from the shared cache
   (``explore/`` in evsmap's cache) once made; ``size_ratio`` = its map size over the trial's,
   ``miou_loss`` = its 3D mIoU minus the trial's, in points.

Every map of a trial reads the same observations, computed once into the shared segmentation
cache (:class:`~evsmap.runner.segcache.SegmentationCache`) by the study's segmenter: the oracle
at a stated accuracy, a trained network, or a user's plug-in.
"""

from __future__ import annotations

import copy
import json
import os
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from evsmap.data import SemanticObservation
from evsmap.data import Sequence as FrameSequence
from evsmap.errors import EvsmapError
from evsmap.explore.space import Space
from evsmap.interfaces import MapUpdater

TRUTH_OBJECTIVES = ("scene_miou", "map_miou", "semantic_accuracy")
"""The objectives that need the sequence's ground-truth voxels."""

MAPS_VERSION = 2
"""Bumped when what a cached baseline record holds changes."""


@dataclass(frozen=True)
class Inputs:
    """What every trial of a study maps: the sequence, its first ``frames`` frames, and the
    segmenter whose observations every map reads.

    Attributes:
        sequence: ``synthetic`` (the built-in room, rendered once into the cache) or any
            reader's path.
        reader, reader_options: the reader (detected from the path when ``None``) and its
            options (for ``synthetic``: frames, width, height, laps, seed, noise...).
        frames: the first N frames (``None``: all).
        segmenter, segmenter_options, weights: the segmenter (``oracle`` with its accuracy
            options, a network with trained weights, a user's plug-in).
    """

    sequence: str = "synthetic"
    reader: str | None = None
    reader_options: dict[str, Any] = field(default_factory=dict)
    frames: int | None = None
    segmenter: str = "oracle"
    segmenter_options: dict[str, Any] = field(default_factory=dict)
    weights: str | None = None

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


DEFAULT_SYNTHETIC: dict[str, Any] = {"frames": 60, "width": 320, "height": 240, "noise": True}
"""The study's default sequence: the built-in living room, one lap of 60 frames at 320x240
(docs/explore.md, "Default length": a lap revisits every wall, so the octree prunes)."""


def open_inputs(inputs: Inputs) -> FrameSequence:
    """The study's sequence (checked to have poses)."""
    from evsmap.readers.detect import open_sequence

    options = dict(inputs.reader_options)
    if inputs.sequence == "synthetic" and inputs.reader in (None, "synthetic"):
        options.setdefault("render", "cached")
    sequence = open_sequence(inputs.sequence, inputs.reader, list(options.items()))
    if not sequence.has_poses:
        raise EvsmapError(f"{inputs.sequence}: no camera poses (a segmentation dataset); "
                          f"explore maps a sequence with poses")
    return sequence


UNTIMED_DROPS = ("update_hz", "rate_ratio", "cached")
"""A map record's fields that are timings (or say where it came from), left out of an untimed
record (:meth:`Bench.labelled_map`)."""

QUALITY = ("precision", "recall", "semantic_accuracy", "map_miou", "scene_miou")
"""The map's 3D quality a trial records (:class:`~evsmap.metrics.mapping.MapQuality`)."""


class Bench:
    """The trials of one study in this process: the sequence, its observations and ground truth
    made once, each trial measured by :meth:`measure`.

    Args:
        space: the study's space.
        inputs: what every trial maps.
        say: where a line of progress goes (the observations, the first baseline maps).
    """

    def __init__(self, space: Space, inputs: Inputs, *, say: Any = None) -> None:
        self.space, self.inputs = space, inputs
        self.say = say or (lambda line: None)
        self.sequence = open_inputs(inputs)
        n = len(self.sequence)
        self.indices = list(range(n if inputs.frames is None else min(inputs.frames, n)))
        if not self.indices:
            raise EvsmapError(f"{inputs.sequence}: no frames to map")
        needs = [o.name for o in space.objectives if o.name in TRUTH_OBJECTIVES]
        if needs and not self.has_truth():
            raise EvsmapError(f"objective {needs[0]} needs ground-truth voxels and "
                              f"{inputs.sequence} has none (the synthetic scenes and synthrooms "
                              f"rooms have them): steer by map_size or rate_ratio (the space's "
                              f"[[objectives]])")
        self._observations: list[SemanticObservation] | None = None
        self._truth: dict[float, Any] = {}
        self._identity: dict[str, dict[str, Any]] = {}

    # ---- what every trial shares
    def segmenter(self) -> Any:
        from evsmap.segmenters.create import create_segmenter

        config = dict(self.inputs.segmenter_options)
        if self.inputs.weights is not None:
            config["weights"] = self.inputs.weights
        return create_segmenter(self.inputs.segmenter, **config)

    def observations_key(self) -> dict[str, Any]:
        """The segmentation cache's key of the study's observations (the runner's keys: the
        same observations are shared with ``evsmap reproduce``'s mapping runs)."""
        from evsmap.measure.engine import is_oracle
        from evsmap.runner.mapping_labels import observations_key, sequence_identity

        frames_id = sequence_identity(self.sequence)
        if self.inputs.weights is not None:
            key = observations_key(self.inputs.segmenter, self.inputs.weights,
                                   self.sequence.name)
        else:
            key = {"segmenter": self.inputs.segmenter, "sequence": self.sequence.name}
            segmenter = self.segmenter()
            if is_oracle(segmenter):  # its profile's settings and its code decide its output
                key.update(segmenter.identity())
        return {**key, **self.inputs.segmenter_options, "frames": frames_id}

    def observations(self) -> list[SemanticObservation]:
        if self._observations is None:
            from evsmap.cache import cache_dir
            from evsmap.runner.segcache import SegmentationCache

            cache = SegmentationCache(cache_dir("segmentation"))
            obs, _, reused = cache.observations(self.segmenter(), self.sequence, self.indices,
                                                key=self.observations_key())
            self.say(f"observations of {self.inputs.segmenter} on {len(self.indices)} frames "
                     + ("from the shared cache" if reused else "computed into the shared cache"))
            self._observations = obs
        return self._observations

    def has_truth(self) -> bool:
        """The sequence has ground-truth voxels (the synthetic scenes, a synthrooms room)."""
        return self.sequence.has_ground_truth

    def truth(self, resolution: float) -> Any:
        """The ground-truth voxels at ``resolution`` (made once per resolution)."""
        if resolution not in self._truth:
            truth = self.sequence.ground_truth(resolution)
            if truth is None:
                raise EvsmapError(f"{self.inputs.sequence}: no ground-truth voxels")
            self._truth[resolution] = truth
        return self._truth[resolution]

    def relabelled(self, inputs: Inputs) -> Bench:
        """This bench with another segmenter's observations (``inputs`` differs from this
        bench's in its segmenter only): the sequence, its frames and ground truth shared, the
        observations and the cache identity its own."""
        other = copy.copy(self)
        other.inputs = inputs
        other.forget_observations()
        return other

    def forget_observations(self) -> None:
        """Drop the observations and their cache identity (made again on first use)."""
        self._observations, self._identity = None, {}

    def labelled_map(self, name: str, options: dict[str, Any],
                     shared: dict[str, Any]) -> dict[str, Any]:
        """``name`` mapping the frames with this bench's observations at ``options`` (the
        shared settings among them): its sizes and 3D quality, exact, so kept in the shared
        cache (``explore/labelled-*.json``; the paired baseline's own entry is read when one
        was made with these observations). No rate: nothing is timed against a reference."""
        from evsmap.fileio import atomic_write_text

        config = {k: v for k, v in options.items() if k not in shared}
        path = self._map_path("labelled", name, config, shared)
        baseline = self._map_path("baseline", name, config, shared)
        for cached in (path, baseline):
            if cached.is_file():
                record: dict[str, Any] = json.loads(cached.read_text())
                return {k: v for k, v in record.items() if k not in UNTIMED_DROPS}
        mapped = self._map(name, options, semantic=True)
        record = {k: v for k, v in _sizes(mapped).items() if k not in UNTIMED_DROPS}
        record.update(_quality(mapped.updater, self.truth(shared["resolution"])))
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(path, json.dumps(record, sort_keys=True))
        return record

    # ---- one trial
    def measure(self, params: dict[str, Any]) -> dict[str, Any]:
        """The trial at ``params`` (a plain record: :func:`trial_record`'s fields)."""
        from evsmap.mapping.threads import update_threads

        start = time.perf_counter()
        shared, own = self.space.split(params)
        mapped = self._map(self.space.updater, {**shared, **own}, semantic=True)
        reference = self._map(self.space.reference, shared, semantic=False)
        trial, ref = _sizes(mapped), _sizes(reference)
        trial.update(_quality(mapped.updater, self.truth(shared["resolution"]))
                     if self.has_truth() else {})
        baseline = self.baseline(shared, ref["update_hz"])
        record = trial_record(trial, reference=ref, baseline=baseline,
                              params=params, shared=shared, threads=update_threads(),
                              wall_s=time.perf_counter() - start)
        return {**record, "labels": self.labels_id()}

    def labels_id(self) -> str:
        """16 hex digits naming the labels every map of this bench reads (the observations'
        cache key: the segmenter, its profile's settings or weights, the code, the frames)."""
        from evsmap.runner.segcache import cache_key

        return cache_key(observations=self.observations_key())

    def _map(self, name: str, options: dict[str, Any], *, semantic: bool) -> Any:
        """``name`` mapping the frames with the options it takes (timed per update)."""
        from evsmap.measure.engine import run_mapping
        from evsmap.measure.evaluators import MapFiles, MapStatistics
        from evsmap.registry import UPDATERS

        taken = UPDATERS.get(name).options
        config = {k: v for k, v in options.items() if k in taken}

        # made before the loop (no memory is measured here)
        updater: MapUpdater = UPDATERS.create(name, **config)
        observations = self.observations() if semantic and updater.uses_semantics else None
        return run_mapping(self.sequence, updater, observations=observations,
                           indices=self.indices, evaluators=[MapStatistics(), MapFiles()],
                           measure_memory=False)

    def baseline(self, shared: dict[str, Any], reference_hz: float) -> dict[str, Any] | None:
        """The paired baseline's record at ``shared`` (from the shared cache once made; its
        ``rate_ratio`` is to ``reference_hz``, the reference timed in the process that made
        it)."""
        if not self.space.baseline:
            return None
        component = baseline_updater(self.space.baseline)
        path = self._map_path("baseline", component.name, component.config, shared)
        if path.is_file():
            record: dict[str, Any] = json.loads(path.read_text())
            return {**record, "cached": True}
        options = {**component.config, **shared}
        mapped = self._map(component.name, options, semantic=True)
        record = _sizes(mapped)
        if self.has_truth():
            record.update(_quality(mapped.updater, self.truth(shared["resolution"])))
        record.update(row=self.space.baseline, updater=component.spec,
                      rate_ratio=record["update_hz"] / reference_hz)
        from evsmap.fileio import atomic_write_text

        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(path, json.dumps(record, sort_keys=True))
        return {**record, "cached": False}

    def _map_path(self, kind: str, name: str, config: dict[str, Any],
                  shared: dict[str, Any]) -> Path:
        """Where the shared cache keeps ``name``'s map at ``config`` and ``shared`` with this
        bench's observations (``kind``: ``baseline``, a paired baseline's record; ``labelled``,
        a map's untimed record)."""
        from evsmap.cache import cache_dir
        from evsmap.runner.segcache import cache_key

        key = cache_key(version=MAPS_VERSION, updater=name, config=config, shared=shared,
                        **self._baseline_identity(name))
        return cache_dir("explore") / f"{kind}-{key}.json"

    def _baseline_identity(self, name: str) -> dict[str, Any]:
        """What every cached map of this bench shares in its cache key: the observations,
        the frames, the code's digests (evsmap's and the updater's package: hashed once per
        process and package, not once per trial)."""
        from evsmap.registry import UPDATERS

        package = UPDATERS.get(name).factory.__module__.split(".")[0]
        if package not in self._identity:
            from evsmap.cache import source_digest

            self._identity[package] = {"observations": self.observations_key(),
                                       "indices": len(self.indices),
                                       "code": [source_digest("evsmap"),
                                                source_digest(package)]}
        return self._identity[package]


def baseline_updater(row: str) -> Any:
    """The updater (a :class:`~evsmap.tables.records.Component`) of Table IV's row ``row``."""
    from evsmap.tables.schema import mapping_table

    table = mapping_table()
    try:
        system = table.row(row)
    except KeyError:
        raise EvsmapError(f"baseline {row!r} is not a row of Table IV (rows: "
                          f"{', '.join(r.id for r in table.rows)})") from None
    if system.updater is None:
        raise EvsmapError(f"baseline {row!r}: Table IV's row has no map updater")
    return system.updater


def _sizes(mapped: Any) -> dict[str, Any]:
    """A mapping pass's rates, size readings and counts (Table IV's reading is ``map_size``)."""
    from evsmap.measure.evaluators import pruned_share
    from evsmap.measure.mapping import MappingRecord
    from evsmap.runner.table4_reading import READINGS, TABLE4_READING

    record = MappingRecord.from_run(mapped, updater=type(mapped.updater).__name__,
                                    segmenter=None)
    values = record.values()
    out: dict[str, Any] = {k: values.get(v) for k, v in READINGS.items()}
    out = {"map_size": values.get(READINGS[TABLE4_READING]),
           **{READINGS[k]: v for k, v in out.items()},
           "update_hz": values["update_hz"], "nodes": values["nodes"],
           "leaves": values["leaves"], "pruned_share": pruned_share(mapped.updater)}
    return out


def _quality(updater: MapUpdater, truth: Any) -> dict[str, Any]:
    from evsmap.measure.evaluators import MapQualityEvaluator

    quality = MapQualityEvaluator(truth).evaluate(updater)
    q = quality.as_dict() if quality is not None else {}
    return {name: q.get(name) for name in QUALITY}


def trial_record(trial: dict[str, Any], *, reference: dict[str, Any],
                 baseline: dict[str, Any] | None, params: dict[str, Any],
                 shared: dict[str, Any], threads: int, wall_s: float) -> dict[str, Any]:
    """A trial's plain record: the map's measurements, the ratios, the reference's and the
    baseline's records beside them.

    ``rate_ratio`` = ``update_hz`` / the reference's (timed in this process); ``size_ratio`` =
    the baseline's ``map_size`` / this map's; ``miou_loss`` = (the baseline's scene mIoU - this
    map's) in points (positive: this map is worse; the scene mIoU counts the ground-truth
    voxels a map dropped, :func:`evsmap.metrics.mapping.scene_miou`)."""
    record = dict(trial)
    record["rate_ratio"] = trial["update_hz"] / reference["update_hz"]
    if baseline is not None:
        record["size_ratio"] = baseline["map_size"] / trial["map_size"]
        if baseline.get("scene_miou") is not None and trial.get("scene_miou") is not None:
            record["miou_loss"] = 100.0 * (baseline["scene_miou"] - trial["scene_miou"])
    record.update(params=dict(params), shared=dict(shared), reference=reference,
                  baseline=baseline, threads=threads, wall_s=wall_s, pid=os.getpid())
    return record
