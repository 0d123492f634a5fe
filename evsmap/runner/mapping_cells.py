"""Mapping runs and Table IV: one system mapping one sequence (an ``extra/mapping/...``
record, timed through the measurement engine, with the segmentation cache's observations), and
Table IV's cells read from those runs so that each map is built once."""

from __future__ import annotations

import hashlib
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from evsmap.data import SemanticObservation
from evsmap.data import Sequence as FrameSequence
from evsmap.errors import EvsmapError
from evsmap.interfaces import MapUpdater
from evsmap.measure.engine import MappingPass, run_mapping
from evsmap.measure.mapping import MappingRecord
from evsmap.runner.cell_base import base_fields, column_quantities, now
from evsmap.runner.context import RunContext
from evsmap.runner.network_cells import build_segmenter
from evsmap.runner.records import CellRecord, needs_text
from evsmap.runner.scannet import SCANNET, is_scannet_sequence, open_scannet
from evsmap.runner.systems import ExtraSystem
from evsmap.tables.schema import CellSpec, Component, mapping_table

MAPPING_WEIGHTS = "nyuv2"
"""The dataset the segmenters of the mapping systems are trained on (40 NYUv2 classes)."""

READINGS = {"saved file": "map_bytes", "octomap_full message": "map_bytes_message",
            "colour-only file": "map_bytes_colour",
            "C++ memory (model)": "octomap_memory_bytes"}
"""The four readings of a map's size every mapping run records (reading -> its value): the file
the system itself saves, the full map as its ROS node sends it (the saved file's bytes except
SSMI's, whose message carries the semantics), the colour-only ``ColorOcTree`` every system can
write, OctoMap's memory model over the system's C++ node (:mod:`evsmap.report.map_size` compares
them)."""

TABLE4_READING = "C++ memory (model)"
"""The reading Table IV's Map Size cells take: of the three, the one whose ratios come closest to
the paper's own Seq.1 rows on the TUM frames (docs/mapping.md, "Which Map Size")."""

MAPPING_PREFIX = "extra/mapping/"
"""What every mapping run's key starts with (:func:`mapping_key`)."""


def mapping_key(row: str, sequence: str, voxel_size: float) -> str:
    """The key of a mapping run's record: ``extra/mapping/<row>/<sequence>@<voxel>m``."""
    return f"{MAPPING_PREFIX}{row}/{sequence}@{voxel_size:g}m"


REFERENCE_ROW = "octomap-cpp"
"""The C++ OctoMap (occupancy only) mapped beside Table IV's systems as a reference."""

PROXY_DATASET = "synthrooms"
"""The dataset a proxy network's weights are trained on (:mod:`evsmap.runner.proxy`)."""
PROXY_LABEL_MODELS = ("feagnet-v1", "feagnet-v2", "fchardnet-70")
"""The proxy networks whose labels a run can map with (``reproduce --train``'s), in the order
tried: the first with synthrooms weights in the weights folder labels the run; with none,
FEAGNet-V1's are the weights named as missing."""


@dataclass(frozen=True)
class LabelSource:
    """Where a semantic mapping run's labels come from, when not the run's default rule
    (its network's NYUv2 weights, else the oracle with the run's profile).

    Attributes:
        kind: ``oracle`` (ground truth with a profile's noise) or ``network`` (a trained
            network's own predictions).
        profile: the oracle's profile (a shipped name or a file).
        model: the network (a segmenter spec).
        dataset: the dataset the network's weights are trained on (its weights are
            ``ctx.weights_choice(model, dataset)``).
    """

    kind: Literal["oracle", "network"]
    profile: str | None = None
    model: str | None = None
    dataset: str | None = None

    @classmethod
    def oracle(cls, profile: str) -> LabelSource:
        return cls("oracle", profile=profile)

    @classmethod
    def network(cls, model: str, dataset: str = PROXY_DATASET) -> LabelSource:
        return cls("network", model=model, dataset=dataset)

    @property
    def slug(self) -> str:
        """The source in a row id: the oracle's profile name, or ``network``."""
        return "network" if self.kind == "network" else Path(str(self.profile)).stem

    def as_dict(self) -> dict[str, Any]:
        """The source as a record's ``inputs["labels"]`` holds it (only the fields set)."""
        return {k: v for k, v in (("kind", self.kind), ("profile", self.profile),
                                  ("model", self.model), ("dataset", self.dataset))
                if v is not None}

    def weights_need(self) -> str:
        """A network source's requirement, ``weights:<model>@<dataset>``."""
        return f"weights:{self.model}@{self.dataset}"


def proxy_source(ctx: RunContext) -> LabelSource:
    """The proxy network that labels a run's synthetic room (:data:`PROXY_LABEL_MODELS`): the
    first with synthrooms weights (``ctx.weights_choice``), else FEAGNet-V1 (whose weights
    its n/a record then names)."""
    for model in PROXY_LABEL_MODELS:
        if ctx.weights_choice(model, PROXY_DATASET) is not None:
            return LabelSource.network(model)
    return LabelSource.network(PROXY_LABEL_MODELS[0])


@dataclass(frozen=True)
class MappingRun:
    """One system mapping one sequence (an ``extra/mapping/...`` record)."""

    row: str
    label: str
    segmenter: Component | None
    updater: Component
    sequence: str
    voxel_size: float
    own_labels: bool = False
    """The segmenter is not a network: its own predictions are the labels (no weights, no
    oracle); a user's system (``--systems``) with such a segmenter."""
    labels: LabelSource | None = None
    """The labels to map with, in place of the default rule (:func:`run_labels`): the
    semantic-detail section's label sources (each with a row id of its own, so its record's
    key names it), and the synthetic room's network labels (``reproduce --synthetic-labels
    network``, a setting of the whole run)."""
    views: bool = True
    """The run saves its map and one segmented frame for the report's views (the
    semantic-detail section's label-source runs do not: they are a row's map again, with
    other labels)."""

    @property
    def key(self) -> str:
        return mapping_key(self.row, self.sequence, self.voxel_size)

    def base_fields(self) -> dict[str, Any]:
        """The fields every record of this run carries (key, row, inputs, ...)."""
        inputs: dict[str, Any] = {
            "segmenter": self.segmenter.spec if self.segmenter else None,
            "updater": self.updater.spec, "sequence": self.sequence,
            "voxel_size": self.voxel_size}
        if self.labels is not None:
            inputs["labels"] = self.labels.as_dict()
        return {"key": self.key, "table": "extra", "row": self.row, "label": self.label,
                "kind": "mapping", "metrics": [], "inputs": inputs}


VARIANT_ROWS = {
    "tfeagmap": ("-direct", "TFEAGMap, direct front end", {"front_end": "direct"}),
    "evsmap": ("-direct", "EVSMap, direct front end", {"front_end": "direct"}),
}
"""Table IV rows also mapped with a named variant of their updater (row suffix, label, options):
TFEAGMap and EVSMap on evsmap's direct front end beside the ``octomap_generator`` both ROS nodes
run (:mod:`evsmap.mapping.generator`), so the report shows what the front end changes, apart
from the node update."""


def mapping_runs(sequences: list[str], voxel_sizes: Sequence[float],
                 systems: Sequence[ExtraSystem] = (), *,
                 reference_on_synthetic: bool = True) -> list[MappingRun]:
    """Table IV's systems (and :data:`VARIANT_ROWS`) plus the C++ OctoMap reference, then the
    user's ``systems`` (``--systems``), on each of ``sequences`` at each of ``voxel_sizes``.
    ``reference_on_synthetic=False`` leaves the reference out on the built-in sequences (the
    Python binding inserts a 640x480 frame at 2 cm in about 1.5 s: 94 s for the synthetic
    room's 60 frames, the longest mapping run; the real sequences keep it)."""
    table = mapping_table()
    runs = []
    for voxel_size in voxel_sizes:
        for seq in sequences:
            for system in table.rows:
                if system.implemented and system.updater is not None:
                    segmenter = system.segmenter_for(MAPPING_WEIGHTS)
                    runs.append(MappingRun(system.id, system.label, segmenter, system.updater,
                                           seq, voxel_size))
                    if system.id in VARIANT_ROWS:
                        suffix, label, options = VARIANT_ROWS[system.id]
                        runs.append(MappingRun(system.id + suffix, label, segmenter,
                                               system.updater.with_options(options), seq,
                                               voxel_size))
            if reference_on_synthetic or seq not in SYNTHETIC_SEQUENCES:
                runs.append(MappingRun(REFERENCE_ROW, "OctoMap (C++)", None,
                                       Component("octomap-cpp"), seq, voxel_size))
            for extra in systems:
                runs.append(MappingRun(extra.id, extra.label, extra.segmenter, extra.updater,
                                       seq, voxel_size, own_labels=extra.segmenter is not None
                                       and not extra.segmenter_is_network))
    return runs


SYNTHETIC_SEQUENCES = ("synthetic", "synthetic-long")
"""The built-in sequences (rendered, with ground truth): the room's one lap, and its long run."""


def synthetic_options(ctx: RunContext, name: str) -> dict[str, Any]:
    """The :class:`~evsmap.synth.sequence.SyntheticSequence` options of a built-in sequence."""
    return dict(ctx.synthetic if name == "synthetic" else ctx.synthetic_long or {})


def open_mapping_sequence(ctx: RunContext, name: str) -> FrameSequence:
    from evsmap.registry import READERS
    from evsmap.runner.context import MAPPING_SEQUENCES

    if is_scannet_sequence(name):
        return open_scannet(ctx, name)
    if name in SYNTHETIC_SEQUENCES:
        # rendered once into the cache shared across runs (TUM layout, read back
        # bit-identical, keyed by the options and the renderer's source), so the mapping runs,
        # the segmentation cache and the timings all read the same frames cheaply
        from evsmap.synth.cached import rendered_folder

        rendered: FrameSequence = READERS.create(
            "tum", path=str(rendered_folder(synthetic_options(ctx, name))))
        return rendered
    path = ctx.dataset_path(name)
    if path is None:
        raise EvsmapError(f"sequence {name!r} not found under {ctx.roots()}")
    info = MAPPING_SEQUENCES[name]
    reader: FrameSequence = READERS.create(info["reader"], path=str(path), **info["options"])
    return reader


def sequence_identity(sequence: FrameSequence) -> str:
    """What a sequence's frames are, for the shared segmentation cache: its folder (resolved)
    and that folder's modification time and size, so frames replaced in place, or another
    rendering of the synthetic scene (its folder names the renderer's source digest), get new
    entries; a sequence that says what its frames are (:meth:`Sequence.frames_identity`, e.g. a
    ScanNet scene read every N-th frame) is taken at its word."""
    own = sequence.frames_identity()
    if own is not None:
        return own
    path = getattr(sequence, "root", None) or getattr(sequence, "path", None)
    if path is None:
        return str(getattr(sequence, "name", "unknown"))
    p = Path(path).resolve()
    try:
        st = p.stat()
        return f"{p}:{st.st_mtime_ns}:{st.st_size}"
    except OSError:
        return str(p)


_WEIGHTS_IDS: dict[tuple[str, int, int, int], str] = {}


def weights_identity(path: str | os.PathLike[str]) -> str:
    """What a weights file's tensors are, for cache keys: ``tensors:<sha256>`` from the card's
    ``tensors_sha256`` when the file has a card, else ``file:<sha256>`` of its bytes. Computed
    once per (path, inode, size, modification time) in this process."""
    path = Path(path)
    st = path.stat()
    memo = (str(path.resolve()), st.st_ino, st.st_size, st.st_mtime_ns)
    found = _WEIGHTS_IDS.get(memo)
    if found is None:
        from evsmap.segmenters.cards import inspect_weights

        card = inspect_weights(path).card
        sha = card.get("tensors_sha256") if card is not None else None
        if isinstance(sha, str) and sha:
            found = f"tensors:{sha}"
        else:
            digest = hashlib.sha256()
            with open(path, "rb") as f:
                for chunk in iter(lambda: f.read(1 << 20), b""):
                    digest.update(chunk)
            found = f"file:{digest.hexdigest()}"
        _WEIGHTS_IDS[memo] = found
    return found


def observations_key(segmenter: str, weights: str | os.PathLike[str],
                     sequence: str) -> dict[str, Any]:
    """The segmentation cache's key of a network's observations: the segmenter, the weights
    file's path and its tensors (:func:`weights_identity`: a file replaced under the same name
    gets a new key), the sequence."""
    return {"segmenter": segmenter, "weights": str(weights),
            "weights_id": weights_identity(weights), "sequence": sequence}


def with_synthetic_labels(ctx: RunContext, runs: list[MappingRun]) -> list[MappingRun]:
    """``runs`` with ``reproduce --synthetic-labels network`` applied: a semantic run on a
    built-in synthetic sequence whose network has no NYUv2 weights (so the oracle would stand
    in) maps with the proxy network's labels (:func:`proxy_source`) instead; the others as
    they are. With ``oracle`` (the default), ``runs`` unchanged."""
    if ctx.synthetic_labels != "network":
        return runs
    from dataclasses import replace

    source = proxy_source(ctx)
    return [replace(run, labels=source)
            if run.labels is None and run.segmenter is not None and not run.own_labels
            and run.sequence in SYNTHETIC_SEQUENCES
            and ctx.weights_choice(run.segmenter.spec, MAPPING_WEIGHTS) is None else run
            for run in runs]


def missing_network_record(run: MappingRun) -> CellRecord:
    """The n/a record of a run told to map with a proxy network's labels
    (:attr:`MappingRun.labels`) whose weights are not in the weights folder: which weights, and
    how to get them."""
    assert run.labels is not None and run.labels.kind == "network"
    need = run.labels.weights_need()
    name = f"{run.labels.model}@{run.labels.dataset}.pt"
    return CellRecord(
        **run.base_fields(), status="na", needs=[need],
        reason=f"{needs_text([need])}: no {run.labels.dataset} weights of "
               f"{' or '.join(PROXY_LABEL_MODELS)} in the weights folder; `evsmap reproduce "
               f"--train` trains them (then `evsmap reproduce --resume --out RUN` maps this "
               f"run), or give --weights DIR holding {name}", started=now())


def unlabelled_record(run: MappingRun) -> CellRecord:
    """The n/a record of a semantic run that cannot be mapped here: its network has no trained
    weights and its sequence no ground-truth labels for the oracle to stand in (or it is told
    to map with a proxy network's labels and that network has no weights:
    :func:`missing_network_record`)."""
    assert run.segmenter is not None
    if run.labels is not None and run.labels.kind == "network":
        return missing_network_record(run)
    need = f"weights:{run.segmenter.spec}@{MAPPING_WEIGHTS}"
    return CellRecord(**run.base_fields(), status="na", needs=[need],
                      reason=needs_text([need]) + f" ({run.sequence} has no ground-truth "
                      f"labels for the oracle)", started=now())


def _missing(ctx: RunContext, sequence: str) -> str | None:
    """The dataset a real sequence needs when it is not under the data roots, else None."""
    dataset = SCANNET if is_scannet_sequence(sequence) else sequence
    if sequence in SYNTHETIC_SEQUENCES or ctx.dataset_path(dataset) is not None:
        return None
    return dataset


def _unlabelled(ctx: RunContext, sequence: str, cache: dict[str, bool]) -> bool:
    if _missing(ctx, sequence) is not None:  # its record says which dataset it needs
        return False
    if sequence not in cache:
        seq = open_mapping_sequence(ctx, sequence)
        cache[sequence] = len(seq) == 0 or seq.frame(0).labels is None
    return cache[sequence]


def lacks_labels(ctx: RunContext, run: MappingRun, cache: dict[str, bool] | None = None) -> bool:
    """A semantic run that cannot be mapped here (:func:`unlabelled_record`): no trained weights
    for its network and no ground-truth labels on its sequence for the oracle to stand in; or
    told to map with a network's labels (:attr:`MappingRun.labels`) that has no weights."""
    if run.labels is not None and run.labels.kind == "network":
        assert run.labels.model is not None and run.labels.dataset is not None
        return ctx.weights_choice(run.labels.model, run.labels.dataset) is None
    return (run.segmenter is not None and not run.own_labels and run.labels is None
            and ctx.weights_path(run.segmenter.spec, MAPPING_WEIGHTS) is None
            and _unlabelled(ctx, run.sequence, {} if cache is None else cache))


@dataclass
class Labels:
    """Where a mapping run's labels come from: the observations (``None``: the updater's own
    segmenter is not needed), each frame's segmentation time (empty: none counted), the
    network's own timing when it was timed apart, the notes saying so, and the source named
    in the segmentation view."""

    observations: list[SemanticObservation] | None = None
    segment_ms: list[float] = field(default_factory=list)
    timing: dict[str, Any] | None = None
    notes: list[str] = field(default_factory=list)
    source: str = "oracle"
    origin: dict[str, Any] = field(default_factory=dict)
    """The source precisely, as the record's ``details["labels"]`` keeps it: ``kind``
    (``oracle``, ``network``, ``segmenter``) and the oracle's ``profile`` and ``settings``
    digest, or the network's ``model``, ``dataset`` and ``weights`` file."""

    @property
    def labels_from(self) -> str:
        """The source in words (the record's ``details["labels_from"]``)."""
        return labels_text(self.origin) if self.origin else self.source


def labels_text(origin: dict[str, Any]) -> str:
    """A :attr:`Labels.origin` in words: ``oracle (profile fitted)``, ``feagnet-v1 with weights
    proxy/best.pt (synthrooms)``, or the segmenter's spec."""
    if origin.get("kind") == "oracle":
        return f"oracle (profile {origin.get('profile')})"
    if origin.get("kind") == "network":
        return (f"{origin.get('model')} with weights {origin.get('weights')} "
                f"({origin.get('dataset')})")
    return str(origin.get("model") or origin.get("kind"))


class _Caches:
    """The segmentation caches of a mapping run: observations shared across runs (keyed by
    segmenter, weights' tensors and the sequence's frames); timings this run's own, never
    another run's."""

    def __init__(self, ctx: RunContext, sequence: FrameSequence) -> None:
        from evsmap.cache import cache_dir
        from evsmap.runner.segcache import SegmentationCache

        self.ctx = ctx
        self.shared = SegmentationCache(cache_dir("segmentation"))
        self.own = SegmentationCache(Path(ctx.out) / "cache" / "segmentation")
        self.frames_id = sequence_identity(sequence)

    def timings(self, segmenter: Any, sequence: FrameSequence, indices: list[int],
                key: dict[str, Any]) -> dict[str, Any]:
        """``segmenter`` timed on the frames in this run (``predict_ms`` and its precision)."""
        timing, _ = self.own.timings(segmenter, sequence, indices, key={
            **key, "threads": self.ctx.threads, "sequence": sequence.name},
            policy=self.ctx.timing_policy())
        return dict(timing)


def _own_labels(run: MappingRun, caches: _Caches, sequence: FrameSequence, indices: list[int],
                labelled: bool) -> Labels | CellRecord:
    """Labels from a segmenter that is not a network: its own predictions, its own time (none
    for one that reads ground truth)."""
    from evsmap.measure.engine import is_oracle

    assert run.segmenter is not None
    spec = run.segmenter.spec
    own = build_segmenter(run.segmenter)
    if is_oracle(own) and not labelled:
        return CellRecord(**run.base_fields(), status="na", needs=[f"labels:{run.sequence}"],
                          reason=f"n/a - {spec} reads ground-truth labels and {run.sequence} "
                                 f"has none", started=now())
    key = {"segmenter": spec, "sequence": sequence.name, "frames": caches.frames_id}
    if is_oracle(own):  # its profile's settings and its code decide its output
        key.update(own.identity(), segmenter=spec)
    observations, segment_ms, reused = caches.shared.observations(own, sequence, indices,
                                                                  key=key)
    timing = None
    if reused:
        timing = caches.timings(own, sequence, indices, {"segmenter": spec})
        segment_ms = timing["predict_ms"]
    if is_oracle(own):  # ground truth read, not a segmentation: no segmentation time
        segment_ms, timing = [], None
    note = (f"labels from {spec} (not a network: no weights"
            + ("; reads ground truth, so segmentation + update = update only)"
               if is_oracle(own) else ")"))
    origin = ({"kind": "oracle", "profile": own.profile.name,
               "settings": own.profile.digest()} if is_oracle(own)
              else {"kind": "segmenter", "model": spec})
    return Labels(observations, segment_ms, timing, [note],
                  source="oracle" if is_oracle(own) else spec,
                  origin=origin if is_oracle(own) else {})


def _network_labels(component: Component, caches: _Caches, sequence: FrameSequence,
                    indices: list[int], choice: Any, dataset: str) -> Labels:
    """Labels from the network ``component`` with its trained weights (``choice``, trained on
    ``dataset``; onnxruntime); its time from this run, even where another run computed the
    observations."""
    spec, weights = component.spec, choice.path
    net = build_segmenter(component, backend="onnxruntime", weights=str(weights))
    observations, segment_ms, reused = caches.shared.observations(
        net, sequence, indices,
        key={**observations_key(spec, weights, sequence.name), "frames": caches.frames_id})
    timing = None
    if reused:  # computed in another run: time the network in this one
        timing = caches.timings(net, sequence, indices, {
            "segmenter": spec, "weights_id": weights_identity(weights),
            "backend": "onnxruntime"})
        segment_ms = timing["predict_ms"]
    return Labels(observations, segment_ms, timing,
                  [f"labels from {spec} with weights {choice.file} (onnxruntime)",
                   choice.note()], source=spec,
                  origin={"kind": "network", "model": spec, "dataset": dataset,
                          "weights": choice.file})


def oracle_observations_key(oracle: Any, ctx: RunContext, sequence: FrameSequence,
                            frames_id: str) -> dict[str, Any]:
    """The shared segmentation cache's key of the oracle's observations: what decides them
    (:meth:`~evsmap.segmenters.oracle.OracleSegmenter.identity`: its profile's name and settings
    digest, seed, k, classes, code), the run's oracle options and the frames; observations made
    under another profile never share an entry."""
    return {**ctx.oracle, **oracle.identity(), "sequence": sequence.name, "frames": frames_id}


def _oracle_labels(run: MappingRun, ctx: RunContext, caches: _Caches, sequence: FrameSequence,
                   indices: list[int], profile: str) -> Labels:
    """Labels from the oracle with ``profile`` (ground truth with the profile's errors); the
    segmentation time of the untrained network on the same frames."""
    from evsmap.measure.engine import is_oracle
    from evsmap.registry import SEGMENTERS

    assert run.segmenter is not None
    spec = run.segmenter.spec
    oracle = SEGMENTERS.create("oracle", **{**ctx.oracle, "profile": profile})
    assert is_oracle(oracle)
    observations, _, _ = caches.shared.observations(
        oracle, sequence, indices, key=oracle_observations_key(oracle, ctx, sequence,
                                                               caches.frames_id))
    net = build_segmenter(run.segmenter, backend=ctx.speed_backend)
    timing = caches.timings(net, sequence, indices,
                            {"segmenter": spec, "backend": ctx.speed_backend})
    segment_ms = timing["predict_ms"]
    note = (f"labels from the oracle segmenter (profile {oracle.profile.name}; "
            f"{_options(ctx.oracle)}: ground truth with the profile's errors), no trained "
            f"weights; segmentation time of the untrained {spec} "
            f"({ctx.speed_backend}) on the same frames in order, {len(segment_ms)} of them "
            f"(until its median was within +-{100 * timing['rel_ci']:.1f} %, "
            f"{timing['stopped']})")
    return Labels(observations, segment_ms, timing, [note],
                  origin={"kind": "oracle", "profile": oracle.profile.name,
                          "settings": oracle.profile.digest()})


def _source_labels(run: MappingRun, ctx: RunContext, caches: _Caches, sequence: FrameSequence,
                   indices: list[int], labelled: bool) -> Labels | CellRecord:
    """Labels from the run's own :attr:`MappingRun.labels`: the oracle with its profile (on a
    labelled sequence), or the network with its weights; else the n/a record saying what is
    missing."""
    from evsmap.runner.context import parse_spec

    source = run.labels
    assert source is not None
    if source.kind == "oracle":
        if not labelled:
            return CellRecord(**run.base_fields(), status="na",
                              needs=[f"labels:{run.sequence}"],
                              reason=f"n/a - the oracle reads ground-truth labels and "
                                     f"{run.sequence} has none", started=now())
        assert source.profile is not None
        return _oracle_labels(run, ctx, caches, sequence, indices, source.profile)
    assert source.model is not None and source.dataset is not None
    choice = ctx.weights_choice(source.model, source.dataset)
    if choice is None:
        return missing_network_record(run)
    name, options = parse_spec(source.model)
    return _network_labels(Component(name, tuple(sorted(options.items()))), caches, sequence,
                           indices, choice, source.dataset)


def run_labels(run: MappingRun, ctx: RunContext, caches: _Caches, sequence: FrameSequence,
               indices: list[int]) -> Labels | CellRecord:
    """The labels a run maps with (:class:`Labels`), or its n/a record: none for a
    geometry-only system; a segmenter's own; the run's own :attr:`MappingRun.labels`; a
    network's with trained NYUv2 weights; the oracle's with the run's profile
    (``ctx.oracle_profile``) on a labelled sequence (the network timed apart); else n/a
    (:func:`unlabelled_record`)."""
    if run.segmenter is None:
        return Labels()
    labelled = bool(indices) and sequence.frame(0).labels is not None
    if run.own_labels:
        return _own_labels(run, caches, sequence, indices, labelled)
    if run.labels is not None:
        return _source_labels(run, ctx, caches, sequence, indices, labelled)
    choice = ctx.weights_choice(run.segmenter.spec, MAPPING_WEIGHTS)
    if choice is not None:
        return _network_labels(run.segmenter, caches, sequence, indices, choice,
                               MAPPING_WEIGHTS)
    if labelled:
        return _oracle_labels(run, ctx, caches, sequence, indices, ctx.oracle_profile)
    return unlabelled_record(run)


def mapping_record(run: MappingRun, ctx: RunContext) -> CellRecord:
    """Map ``run.sequence`` with ``run``'s system; time each update, add the segmentation time
    per frame, measure the map file and (where the sequence has 3D ground truth: the synthetic
    room, a ScanNet scene) its 3D quality."""
    from evsmap.measure.contention import CalibrationLog, Probe, contention, machine_log_path

    dataset = _missing(ctx, run.sequence)
    if dataset is not None:
        need = f"dataset:{dataset}"
        return CellRecord(**run.base_fields(), status="na", needs=[need],
                          reason=needs_text([need]), started=now())
    sequence = open_mapping_sequence(ctx, run.sequence)
    n = len(sequence) if ctx.frames is None else min(ctx.frames, len(sequence))
    indices = list(range(n))
    caches = _Caches(ctx, sequence)
    before = Probe.take()  # the machine around the timed part (segmentation and update)
    labels = run_labels(run, ctx, caches, sequence, indices)
    if isinstance(labels, CellRecord):
        return labels
    mapped = _map(run, ctx, sequence, indices, labels.observations)
    machine = contention(before, Probe.take(),
                         CalibrationLog(Path(ctx.out) / "cache" / "calibration.json",
                                        machine_path=machine_log_path()))
    record = MappingRecord.from_run(
        mapped, updater=run.updater.spec, segmenter=None if run.segmenter is None
        else run.segmenter.spec, segment_ms=labels.segment_ms)
    values, details = _values_and_details(record, mapped, labels)
    if run.segmenter is not None:  # which labels the semantic figures used
        details["labels_from"] = labels.labels_from
        if labels.origin:
            details["labels"] = labels.origin
    notes = labels.notes + [
        f"{n} frames of {sequence.name} at {run.voxel_size:g} m; rates are medians over "
        f"frames (update only; segmentation + update = the median segmentation time + the "
        f"median update time)"]
    _add_contention(machine, details, notes)
    truth = _ground_truth(run, ctx, sequence) if mapped.updater.has_leaf_map else None
    if truth is not None:
        _add_quality(truth, mapped.updater, values, details)
    if run.sequence in SYNTHETIC_SEQUENCES and mapped.updater.has_leaf_map and run.views:
        _save_artifacts(run, ctx, mapped.updater, sequence, indices, labels)
    return CellRecord(**run.base_fields(), status="ok", values=values, notes=notes,
                      details=details)


def _map(run: MappingRun, ctx: RunContext, sequence: FrameSequence, indices: list[int],
         observations: list[SemanticObservation] | None) -> MappingPass:
    """The timed mapping pass; the map's own memory is measured from before the updater is made
    to its files (the observations were computed beforehand)."""
    from evsmap.measure.evaluators import MapFiles, MapStatistics, PrunedShare
    from evsmap.measure.growth import MapGrowth, growth_every, growth_points
    from evsmap.registry import UPDATERS

    n = len(indices)
    return run_mapping(
        sequence, lambda: UPDATERS.create(run.updater.name, resolution=run.voxel_size,
                                          **run.updater.config),
        observations=observations, indices=indices,
        evaluators=[MapStatistics(), MapFiles(), PrunedShare()],
        growth=MapGrowth(every=growth_every(n, growth_points(n, quick=ctx.quick))))


def _values_and_details(record: MappingRecord, mapped: MappingPass,
                        labels: Labels) -> tuple[dict[str, float], dict[str, Any]]:
    """The cell record's ``values`` (:meth:`MappingRecord.values`, with the share of pruned
    leaves) and ``details`` (per-frame times, counts, front end, growth, precision)."""
    values = record.values()
    share = mapped.results["pruned_share"]  # on the finished map's one tree (PrunedShare)
    if share is not None:
        values["pruned_share"] = float(share)
    details: dict[str, Any] = {
        "update_ms": record.update_ms, "segment_ms": record.segment_ms,
        "nodes": record.nodes, "leaves": record.leaves, "sequence_name": record.sequence,
        **values, "front_end": record.front_end, "growth": mapped.results["growth"]}
    if labels.timing is not None:
        details["segment_timing"] = {k: labels.timing[k] for k in
                                     ("rel_ci", "stopped", "warmup", "policy")
                                     if k in labels.timing}
    details["rel_ci"] = segment_update_precision(record.update_ms, record.segment_ms)
    return values, details


def _add_contention(machine: dict[str, Any], details: dict[str, Any], notes: list[str]) -> None:
    """The machine's load around the timed part, and a flag where it was contended."""
    details["contention"] = machine
    details["calibration_gmacs"] = math.sqrt(machine["before"]["calibration_gmacs"]
                                             * machine["after"]["calibration_gmacs"])
    if machine["contended"]:
        from evsmap.measure.contention import describe

        flag = describe(machine) + " around this mapping run"
        details["timing_flag"] = flag
        notes.append(f"timing flagged - {flag}")


def _ground_truth(run: MappingRun, ctx: RunContext, sequence: FrameSequence) -> Any:
    """The scene's voxels at the run's voxel size: the synthetic room's (rebuilt from its
    options; the sequence mapped is its rendering read back), a ScanNet scene's labelled mesh;
    None for a sequence without 3D ground truth."""
    if run.sequence in SYNTHETIC_SEQUENCES:
        from evsmap.synth.cached import cached_ground_truth

        return cached_ground_truth(synthetic_options(ctx, run.sequence), run.voxel_size)
    return sequence.ground_truth(run.voxel_size) if sequence.has_ground_truth else None


def _add_quality(truth: Any, updater: MapUpdater, values: dict[str, float],
                 details: dict[str, Any]) -> None:
    """The map's 3D quality against ``truth`` (outside the memory scope): in
    ``details["quality"]``, its finite fractions in ``values``."""
    from evsmap.measure.evaluators import MapQualityEvaluator

    quality = MapQualityEvaluator(truth).evaluate(updater)
    q = quality.as_dict() if quality is not None else {}
    details["quality"] = q
    for name in ("precision", "recall", "semantic_accuracy", "semantic_accuracy_all",
                 "map_miou", "scene_miou"):
        if q.get(name) is not None and np.isfinite(q[name]):
            values[name] = float(q[name])


def _save_artifacts(run: MappingRun, ctx: RunContext, updater: MapUpdater,
                    sequence: FrameSequence,
                    indices: list[int], labels: Labels) -> None:
    """The map's points (for the views of Table IV's maps) and one segmented frame."""
    if run.voxel_size == ctx.voxel_size:  # the views show Table IV's maps
        _save_map_artifact(updater, run, ctx)
    if labels.observations is not None:
        middle = len(indices) // 2
        _save_segmentation_artifact(sequence, indices[middle], labels.observations[middle],
                                    run, ctx, labels)


def _options(config: dict[str, Any]) -> str:
    return ", ".join(f"{k}={v}" for k, v in sorted(config.items())) or "defaults"


def _save_map_artifact(updater: MapUpdater, run: MappingRun, ctx: RunContext) -> None:
    from evsmap.updaters.export import occupied_points

    centres, rgb, labels = occupied_points(updater)
    folder = Path(ctx.out) / "artifacts"
    folder.mkdir(parents=True, exist_ok=True)
    n = len(centres)
    np.savez_compressed(
        folder / f"map-{run.row}-{run.sequence}.npz", centres=centres.astype(np.float32),
        labels=labels if labels is not None else np.full(n, -1, dtype=np.int16),
        colors=rgb if rgb is not None else np.zeros((n, 3), dtype=np.uint8),
        resolution=np.float64(run.voxel_size))


def _save_segmentation_artifact(sequence: FrameSequence, index: int,
                                observation: SemanticObservation, run: MappingRun,
                                ctx: RunContext, labels: Labels) -> None:
    folder = Path(ctx.out) / "artifacts"
    path = folder / f"seg-{labels.source}-{run.sequence}.npz"
    if path.exists():
        return
    folder.mkdir(parents=True, exist_ok=True)
    frame = sequence.frame(index)
    title = (f"{labels.labels_from} on {sequence.name} frame {index}"
             + (f" ({_options(ctx.oracle)})" if labels.source == "oracle" else ""))
    arrays: dict[str, Any] = {"rgb": frame.rgb, "gt": frame.labels, "pred": observation.argmax,
                              "title": np.str_(title)}
    np.savez_compressed(path, **arrays)


def runtime_sequence(sequences: list[str], runs: dict[str, CellRecord],
                     voxel: float) -> tuple[str, bool]:
    """The one sequence Table IV's Runtime column is measured on for every row: the first of
    the column's ``sequences`` that every implemented Table IV system mapped here, else the
    synthetic one (which every system can map, with the oracle's labels). Returns it and
    whether it is that fallback."""
    rows = [r.id for r in mapping_table().rows
            if r.implemented and r.updater is not None]
    for seq in sequences:
        found = [runs.get(mapping_key(row, seq, voxel)) for row in rows]
        if all(r is not None and r.status == "ok" for r in found):
            return seq, False
    return "synthetic", True


def segment_update_precision(update_ms: list[float], segment_ms: list[float]) -> float | None:
    """The precision of ``segment_update_hz`` (1000 / (median update + median segmentation)):
    each median's 95 % bootstrap interval, their half-widths added, over the sum."""
    from evsmap.measure.timing_policy import median_ci, relative_half_width, sum_precision

    parts = []
    for times in (update_ms, segment_ms):
        if times:
            median, low, high = median_ci(times)
            parts.append((median, relative_half_width(median, low, high)))
    return sum_precision(parts) if parts else None


def table4_record(spec: CellSpec, runs: dict[str, CellRecord], ctx: RunContext) -> CellRecord:
    """A Table IV cell from the mapping runs: the map size on its sequence, or the end-to-end
    rate on the one sequence every row's rate comes from (:func:`runtime_sequence`), so the
    column compares systems on the same frames."""
    base = base_fields(spec)
    voxel = spec.voxel_size or ctx.voxel_size

    def run_of(seq: str) -> CellRecord | None:
        return runs.get(mapping_key(spec.row, seq, voxel))

    quantities = column_quantities(spec)
    values, notes, details = {}, [], {}
    for col, q in quantities.items():
        if q == "map_size":
            source = run_of(spec.datasets[0])
            if source is None or source.status != "ok":
                return _from_failed(spec, source)
            value = READINGS[TABLE4_READING]
            if source.values.get(value) is None:
                return CellRecord(**base, status="na", reason=f"n/a - {spec.row} has no "
                                  f"{TABLE4_READING}", started=now())
            values[col] = source.values[value]
            notes += [f"Map Size read as the {TABLE4_READING} (the saved file: "
                      f"{source.values['map_bytes'] / 1e6:.3f} MB)"] + source.notes
            details[col] = {"source": source.key}
        else:  # runtime_hz
            seq, fallback = runtime_sequence(list(spec.datasets), runs, voxel)
            source = run_of(seq)
            if source is None or source.status != "ok":
                return _from_failed(spec, source)
            values[col] = source.values["segment_update_hz"]
            base["inputs"]["sequence"] = seq
            notes.append(f"end-to-end rate measured on {seq} for every row"
                         + (" (no sequence of the paper's could be mapped by every system "
                            "here)" if fallback else "") + "; " + "; ".join(source.notes))
            details[col] = {"source": source.key}
            for name in ("timing_flag", "calibration_gmacs", "rel_ci"):
                if (source.details or {}).get(name):
                    details[name] = source.details[name]
    return CellRecord(**base, status="ok", values=values, notes=notes, details=details,
                      started=now())


def _from_failed(spec: CellSpec, source: CellRecord | None) -> CellRecord:
    if source is None:
        return CellRecord(**base_fields(spec), status="error", error="its mapping run did not run",
                          started=now())
    return CellRecord(**base_fields(spec), status=source.status, needs=source.needs,
                      reason=source.reason, error=source.error, started=now())
