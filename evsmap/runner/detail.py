"""The semantic-detail section: Table IV's map updates, one network feeding all of them, scored
in 3D on ScanNet's labelled meshes (and on the synthetic room, so the comparison is always
there).

The paper says EVSMap "maintains the same level of detail in semantic information
representation" while its map shrinks, and shows pictures (Fig. 7). Here every Table IV update
maps the same frames with the same labels (EVSMap's network with its NYUv2 weights where they
are, else the oracle on the sequence's ground-truth labels), so that the maps differ by the
update alone, and each map is scored against the scene's voxelised ground truth. With one
network, TESAMap and TFEAGMap are the same system (semantic_slam's update), as are MESAMap and
EVSMap (the multi-class Bayesian update): the section has one row for each update, and ORGBMap
for geometry. The records are ordinary mapping runs (``extra/mapping/detail-<row>/...``).

How the synthetic room's semantic figures depend on the labels: besides the run's own labels,
TESAMap and EVSMap map the synthetic room again (Table IV's voxel size, the same frames) with
each other label source (:func:`label_sources`): the oracle under each shipped profile
(``per-pixel``, ``fitted``, ``noise-free``) and a trained proxy network's own labels
(:func:`evsmap.runner.mapping_plan.proxy_source`: the first of FEAGNet-V1, FEAGNet-V2,
FCHarDNet-70 with synthrooms weights), one record each,
``extra/mapping/detail-labels-<source>-<row>/synthetic@<voxel>m`` (``<source>``: the profile's
name or ``network``); without proxy weights one n/a record, ``detail-labels-network``, says which
weights are missing and how to get them.

ScanNet scenes: :mod:`evsmap.runner.scannet`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from evsmap.runner.scannet import SCANNET, scannet_scenes, scannet_sequence

if TYPE_CHECKING:  # the report imports this module's names: it stays light (no torch)
    from evsmap.runner.context import RunContext
    from evsmap.runner.mapping_plan import LabelSource, MappingRun
    from evsmap.tables.schema import Component

DETAIL_PREFIX = "detail-"
"""What the section's row ids start with."""
DETAIL_ROWS = ("orgbmap", "tesamap", "evsmap")
"""Table IV's rows whose updates the section maps (one network: TFEAGMap maps as TESAMap,
MESAMap as EVSMap)."""
LABELS = {"orgbmap": "ORGBMap", "tesamap": "TESAMap (= TFEAGMap with one network)",
          "evsmap": "EVSMap (printed MVSMMap; = MESAMap with one network)"}
"""The section's row labels: with one network TFEAGMap maps as TESAMap and MESAMap as EVSMap."""
NETWORK_ROW = "evsmap"
"""The row whose network labels every semantic row (EVSMap's FEAGNet-V2, NYUv2 weights)."""
SEMANTIC_DETAIL_TOLERANCE = 0.01
"""The claim "EVSMap keeps TESAMap's semantic detail" holds where EVSMap's 3D scene mIoU is at
most this much (1 point) below TESAMap's, on the same frames and labels."""


SENSITIVITY_ROWS = ("tesamap", "evsmap")
"""The rows mapped again with each label source (the two the claim compares)."""
SENSITIVITY_SEQUENCE = "synthetic"
"""The sequence the label sources are compared on (the one every run has)."""
LABELS_PREFIX = DETAIL_PREFIX + "labels-"
"""What the rows of the label-source runs start with."""


def detail_row(row: str) -> str:
    return DETAIL_PREFIX + row


def is_detail(row: str) -> bool:
    """Whether a record's row is one of the section's."""
    return row.startswith(DETAIL_PREFIX)


def sensitivity_row(slug: str, row: str | None = None) -> str:
    """The row id of ``row`` mapped with the label source ``slug``
    (:attr:`~evsmap.runner.mapping_plan.LabelSource.slug`), ``detail-labels-<slug>-<row>``;
    without ``row``, the source's one n/a record, ``detail-labels-<slug>``."""
    return LABELS_PREFIX + slug + ("" if row is None else f"-{row}")


def is_sensitivity(row: str) -> bool:
    """Whether a record's row is a label-source run (:func:`sensitivity_row`)."""
    return row.startswith(LABELS_PREFIX)


def sensitivity_system(row: str) -> str | None:
    """The detail row (:data:`SENSITIVITY_ROWS`) a label-source run's row maps, None for a
    source's n/a record."""
    return next((r for r in SENSITIVITY_ROWS if row.endswith("-" + r)), None)


def default_source(ctx: RunContext, segmenter: Component) -> LabelSource | None:
    """The label source the section's own rows use on the synthetic room: None where the
    network has NYUv2 weights (its labels), else the proxy network's
    (``--synthetic-labels network``) or the oracle with the run's profile."""
    from evsmap.runner.mapping_plan import MAPPING_WEIGHTS, LabelSource, proxy_source

    if ctx.weights_choice(segmenter.spec, MAPPING_WEIGHTS) is not None:
        return None
    if ctx.synthetic_labels == "network":
        return proxy_source(ctx)
    return LabelSource.oracle(ctx.oracle_profile)


def label_sources(ctx: RunContext, segmenter: Component) -> list[LabelSource]:
    """The label sources the synthetic room is mapped with besides the run's own
    (:func:`default_source`): the oracle under each shipped profile, then the proxy network."""
    from evsmap.runner.mapping_plan import LabelSource, proxy_source
    from evsmap.segmenters.oracle_profile import PROFILE_NAMES

    own = default_source(ctx, segmenter)
    sources = [LabelSource.oracle(name) for name in PROFILE_NAMES] + [proxy_source(ctx)]
    return [s for s in sources if s != own]


def sensitivity_runs(ctx: RunContext, segmenter: Component) -> list[MappingRun]:
    """The synthetic room mapped by :data:`SENSITIVITY_ROWS` with each of
    :func:`label_sources`, at Table IV's voxel size; a network source without weights is one
    n/a run (:func:`evsmap.runner.mapping_labels.missing_network_record`) instead of two."""
    from evsmap.runner.mapping_plan import MappingRun
    from evsmap.tables.schema import mapping_table

    rows = {r.id: r for r in mapping_table().rows}
    evsmap_updater = rows[NETWORK_ROW].updater
    assert evsmap_updater is not None
    runs = []
    for source in label_sources(ctx, segmenter):
        if source.kind == "network" and ctx.weights_choice(
                str(source.model), str(source.dataset)) is None:
            runs.append(MappingRun(
                sensitivity_row(source.slug), "TESAMap and EVSMap, a proxy network's labels",
                segmenter, evsmap_updater, SENSITIVITY_SEQUENCE, ctx.resolution,
                labels=source, views=False))
            continue
        for row_id in SENSITIVITY_ROWS:
            updater = rows[row_id].updater
            assert updater is not None
            runs.append(MappingRun(sensitivity_row(source.slug, row_id),
                                   f"{LABELS[row_id]}, labels: {source.slug}", segmenter,
                                   updater, SENSITIVITY_SEQUENCE, ctx.resolution,
                                   labels=source, views=False))
    return runs


def detail_runs(ctx: RunContext) -> list[MappingRun]:
    """The section's mapping runs: each of :data:`DETAIL_ROWS` on the synthetic room and on
    each ScanNet scene (one n/a run naming the dataset when it is not under the data root), at
    Table IV's voxel size; then the synthetic room with the other label sources
    (:func:`sensitivity_runs`)."""
    from evsmap.runner.mapping_plan import MappingRun
    from evsmap.tables.schema import mapping_table

    table = mapping_table()
    rows = {r.id: r for r in table.rows}
    segmenter = rows[NETWORK_ROW].segmenter_for("nyuv2")
    scenes = scannet_scenes(ctx)
    sequences = ["synthetic"] + ([scannet_sequence(s) for s in scenes] or [SCANNET])
    runs = []
    for seq in sequences:
        for row_id in DETAIL_ROWS:
            system = rows[row_id]
            assert system.updater is not None
            runs.append(MappingRun(detail_row(row_id), LABELS[row_id],
                                   segmenter if system.segmenter is not None else None,
                                   system.updater, seq, ctx.resolution))
    assert segmenter is not None
    return runs + sensitivity_runs(ctx, segmenter)


__all__ = ["DETAIL_PREFIX", "DETAIL_ROWS", "LABELS", "LABELS_PREFIX", "NETWORK_ROW",
           "SEMANTIC_DETAIL_TOLERANCE", "SENSITIVITY_ROWS", "SENSITIVITY_SEQUENCE",
           "default_source", "detail_row", "detail_runs", "is_detail", "is_sensitivity",
           "label_sources", "sensitivity_row", "sensitivity_runs", "sensitivity_system"]
