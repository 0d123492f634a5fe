"""The labels a mapping run maps with (:func:`run_labels`): a network's with trained weights, the
oracle's with a profile, a segmenter's own, or the n/a record saying what is missing; the
segmentation caches' keys (what a sequence's frames and a weights file's tensors are)."""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from evsmap.data import SemanticObservation
from evsmap.data import Sequence as FrameSequence
from evsmap.runner.cell_base import now
from evsmap.runner.context import RunContext
from evsmap.runner.mapping_plan import (
    MAPPING_WEIGHTS,
    PROXY_LABEL_MODELS,
    MappingRun,
    missing_dataset,
    open_mapping_sequence,
)
from evsmap.runner.network_cells import build_segmenter
from evsmap.runner.records import CellRecord, needs_text
from evsmap.tables.schema import Component


def sequence_identity(sequence: FrameSequence) -> str:
    """What a sequence's frames are, for the shared segmentation cache: its folder (resolved)
    and that folder's modification time and size, so frames replaced in place, or another
    rendering of the synthetic scene (its folder names the renderer's source digest), get new
    entries; a sequence that says what its frames are (:meth:`Sequence.frames_identity`, e.g. a
    ScanNet scene read every N-th frame) is taken at its word."""
    own = sequence.frames_identity()
    if own is not None:
        return own
    if sequence.folder is None:
        return sequence.name
    p = sequence.folder.resolve()
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


def _unlabelled(ctx: RunContext, sequence: str, cache: dict[str, bool]) -> bool:
    if missing_dataset(ctx, sequence) is not None:  # its record says which dataset it needs
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


class LabelCaches:
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


def _own_labels(run: MappingRun, caches: LabelCaches, sequence: FrameSequence, indices: list[int],
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


def _network_labels(component: Component, caches: LabelCaches, sequence: FrameSequence,
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


def _oracle_labels(run: MappingRun, ctx: RunContext, caches: LabelCaches, sequence: FrameSequence,
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
            f"{options_text(ctx.oracle)}: ground truth with the profile's errors), no trained "
            f"weights; segmentation time of the untrained {spec} "
            f"({ctx.speed_backend}) on the same frames in order, {len(segment_ms)} of them "
            f"(until its median was within +-{100 * timing['rel_ci']:.1f} %, "
            f"{timing['stopped']})")
    return Labels(observations, segment_ms, timing, [note],
                  origin={"kind": "oracle", "profile": oracle.profile.name,
                          "settings": oracle.profile.digest()})


def _source_labels(run: MappingRun, ctx: RunContext, caches: LabelCaches, sequence: FrameSequence,
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


def run_labels(run: MappingRun, ctx: RunContext, caches: LabelCaches, sequence: FrameSequence,
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


def options_text(config: dict[str, Any]) -> str:
    """Options in words, ``k=v`` sorted by name (``defaults`` when none)."""
    return ", ".join(f"{k}={v}" for k, v in sorted(config.items())) or "defaults"
