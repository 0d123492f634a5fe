"""The mapping runs a reproduction plans: one system mapping one sequence at one voxel size
(:class:`MappingRun`, an ``extra/mapping/...`` record), Table IV's systems with their variants and
the C++ OctoMap reference, where their labels come from when not the default rule
(:class:`LabelSource`), and the sequences they read."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from evsmap.data import Sequence as FrameSequence
from evsmap.errors import EvsmapError
from evsmap.runner.context import RunContext
from evsmap.runner.scannet import SCANNET, is_scannet_sequence, open_scannet
from evsmap.runner.systems import ExtraSystem
from evsmap.tables.schema import Component, mapping_table

MAPPING_WEIGHTS = "nyuv2"
"""The dataset the segmenters of the mapping systems are trained on (40 NYUv2 classes)."""


MAPPING_PREFIX = "extra/mapping/"
"""What every mapping run's key starts with (:func:`mapping_key`)."""


def mapping_key(row: str, sequence: str, resolution: float) -> str:
    """The key of a mapping run's record: ``extra/mapping/<row>/<sequence>@<voxel>m``."""
    return f"{MAPPING_PREFIX}{row}/{sequence}@{resolution:g}m"


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
    resolution: float
    own_labels: bool = False
    """The segmenter is not a network: its own predictions are the labels (no weights, no
    oracle); a user's system (``--systems``) with such a segmenter."""
    labels: LabelSource | None = None
    """The labels to map with, in place of the default rule
    (:func:`~evsmap.runner.mapping_labels.run_labels`): the semantic-detail section's label
    sources (each with a row id of its own, so its record's key names it), and the synthetic
    room's network labels (``reproduce --synthetic-labels network``, a setting of the whole
    run)."""
    views: bool = True
    """The run saves its map and one segmented frame for the report's views (the
    semantic-detail section's label-source runs do not: they are a row's map again, with
    other labels)."""

    @property
    def key(self) -> str:
        return mapping_key(self.row, self.sequence, self.resolution)

    def base_fields(self) -> dict[str, Any]:
        """The fields every record of this run carries (key, row, inputs, ...)."""
        inputs: dict[str, Any] = {
            "segmenter": self.segmenter.spec if self.segmenter else None,
            "updater": self.updater.spec, "sequence": self.sequence,
            "resolution": self.resolution}
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


def mapping_runs(sequences: list[str], resolutions: Sequence[float],
                 systems: Sequence[ExtraSystem] = (), *,
                 reference_on_synthetic: bool = True) -> list[MappingRun]:
    """Table IV's systems (and :data:`VARIANT_ROWS`) plus the C++ OctoMap reference, then the
    user's ``systems`` (``--systems``), on each of ``sequences`` at each of ``resolutions``.
    ``reference_on_synthetic=False`` leaves the reference out on the built-in sequences (the
    Python binding inserts a 640x480 frame at 2 cm in about 1.5 s: 94 s for the synthetic
    room's 60 frames, the longest mapping run; the real sequences keep it)."""
    table = mapping_table()
    runs = []
    for resolution in resolutions:
        for seq in sequences:
            for system in table.rows:
                if system.implemented and system.updater is not None:
                    segmenter = system.segmenter_for(MAPPING_WEIGHTS)
                    runs.append(MappingRun(system.id, system.label, segmenter, system.updater,
                                           seq, resolution))
                    if system.id in VARIANT_ROWS:
                        suffix, label, options = VARIANT_ROWS[system.id]
                        runs.append(MappingRun(system.id + suffix, label, segmenter,
                                               system.updater.with_options(options), seq,
                                               resolution))
            if reference_on_synthetic or seq not in SYNTHETIC_SEQUENCES:
                runs.append(MappingRun(REFERENCE_ROW, "OctoMap (C++)", None,
                                       Component("octomap-cpp"), seq, resolution))
            for extra in systems:
                runs.append(MappingRun(extra.id, extra.label, extra.segmenter, extra.updater,
                                       seq, resolution, own_labels=extra.segmenter is not None
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


def missing_dataset(ctx: RunContext, sequence: str) -> str | None:
    """The dataset a real sequence needs when it is not under the data roots, else None."""
    dataset = SCANNET if is_scannet_sequence(sequence) else sequence
    if sequence in SYNTHETIC_SEQUENCES or ctx.dataset_path(dataset) is not None:
        return None
    return dataset
